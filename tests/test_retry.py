"""Transport faults: sorted by classify, retried with capped backoff inside the wall-clock budget."""

from __future__ import annotations

import pytest

from autoresearch.proposers.base import FatalAPIError, Proposal, TransientAPIError
from autoresearch.proposers.retry import RetryBudgetSpent, RetryPolicy, call_with_retries, classify


class Clock:
    """A fake monotonic clock that sleep() advances."""

    def __init__(self) -> None:
        self.now, self.sleeps = 0.0, []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def flaky(*outcomes):
    calls = iter(outcomes)

    def call() -> Proposal:
        outcome = next(calls)
        if isinstance(outcome, Exception):
            raise outcome
        return outcome

    return call


@pytest.mark.parametrize(
    ("status", "message", "expected"),
    [
        (None, "Connection reset", TransientAPIError),
        (429, "Rate limit reached", TransientAPIError),
        (529, "Overloaded", TransientAPIError),
        (500, "Internal error", TransientAPIError),
        (408, "Request timeout", TransientAPIError),
        (401, "invalid x-api-key", FatalAPIError),
        (403, "forbidden", FatalAPIError),
        (402, "payment required", FatalAPIError),
        (429, "You exceeded your current quota insufficient_quota", FatalAPIError),
        (400, "Your credit balance is too low", FatalAPIError),
        (400, "tool_choice is not supported", type(None)),
        (404, "model not found", type(None)),
    ],
)
def test_classify(status, message, expected):
    assert isinstance(classify(status, message, {"retry-after": "3"}), expected)


def test_retry_after_is_read_from_the_headers():
    assert classify(429, "slow", {"retry-after-ms": "1500"}).retry_after == 1.5
    assert classify(503, "busy", {"retry-after": "7"}).retry_after == 7.0
    assert classify(503, "busy", {}).retry_after is None


def test_faults_are_retried_with_capped_backoff_and_noted():
    clock = Clock()
    ok = Proposal(kind="propose", overrides={"EPOCHS": 12})
    faults = [TransientAPIError("529: Overloaded")] * 6 + [TransientAPIError("429: slow", retry_after=500.0)]
    proposal = call_with_retries(
        flaky(*faults, ok), policy=RetryPolicy(base_s=2, cap_s=60), sleep=clock.sleep, clock=clock
    )
    assert proposal.kind == "propose" and proposal.overrides == {"EPOCHS": 12}
    assert clock.sleeps == [2, 4, 8, 16, 32, 60, 60]  # doubling, capped, retry-after capped too
    assert (
        len(proposal.notes["transport_faults"]) == 7
        and "529: Overloaded" in proposal.notes["transport_faults"][0]
    )


def test_retries_never_sleep_past_the_wall_clock_budget():
    clock = Clock()
    fault = TransientAPIError("429: slow down", retry_after=30.0)
    with pytest.raises(RetryBudgetSpent, match="wall-clock budget"):
        call_with_retries(flaky(fault, fault), seconds_left=10.0, sleep=clock.sleep, clock=clock)
    # a retry-after beyond the budget ends it at once, even though the sleep itself would be capped
    fault = TransientAPIError("429: slow down", retry_after=3000.0)
    with pytest.raises(RetryBudgetSpent):
        call_with_retries(flaky(fault), seconds_left=600.0, sleep=clock.sleep, clock=clock)
    assert clock.sleeps == []


def test_a_lasting_outage_ends_at_the_retry_window():
    clock = Clock()
    proposal = call_with_retries(
        flaky(*[TransientAPIError("503: down")] * 100),
        policy=RetryPolicy(base_s=1, cap_s=10, window_s=60),
        sleep=clock.sleep,
        clock=clock,
    )
    assert proposal.kind == "invalid" and "retry window" in proposal.error and clock.now <= 60


def test_fatal_errors_are_not_retried():
    clock = Clock()
    with pytest.raises(FatalAPIError):
        call_with_retries(flaky(FatalAPIError("bad key", "auth")), sleep=clock.sleep, clock=clock)
    assert clock.sleeps == []
