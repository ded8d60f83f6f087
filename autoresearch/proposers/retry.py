"""Transport faults of an LLM API, sorted and retried by the orchestrator (not by the SDK).

:func:`classify` turns an SDK error into what the campaign should do with it:

- a transport fault (429 rate limit, 408/409, 5xx with 529 "overloaded", a timeout, a dropped
  connection) -> :class:`TransientAPIError`: retried by :func:`call_with_retries` with capped
  exponential backoff that honours ``retry-after`` and never sleeps past the campaign's wall-clock
  budget; not the proposer's failure;
- authentication or permission (401, 403), or a spend limit (402, or a 400/403/429 whose message
  speaks of credit, billing or quota) -> :class:`FatalAPIError`: the campaign stops at once;
- anything else (400, 404, 413, 422, ...) -> None: the caller makes it an invalid proposal.

The SDK clients are built with ``max_retries=0`` so that these retries, which see the budget, govern.
"""

from __future__ import annotations

import dataclasses
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import ModuleType

from autoresearch.proposers.base import FatalAPIError, Proposal, TransientAPIError
from autoresearch.proposers.tools import safe_text

SPEND_LIMIT = re.compile(r"credit|billing|spend(ing)? limit|quota|usage limit|payment", re.IGNORECASE)
TRANSIENT_STATUS = frozenset({408, 409, 429})


def error_text(message: str) -> str:
    """A server's error message on one line, short and safe to print."""
    return safe_text(" ".join(str(message).split())[:500])


def sdk_error(err: Exception, sdk: ModuleType, *, with_code: bool = False) -> Proposal:
    """An error of the anthropic or openai SDK (both generated with the same error classes):
    raise what :func:`classify` makes of it, else an invalid proposal naming it. ``with_code``
    adds the error's ``code`` to the message (OpenAI puts e.g. ``insufficient_quota`` there)."""
    if isinstance(err, sdk.APIStatusError):
        message = f"{err.message} {err.code or ''}" if with_code else err.message
        verdict = classify(err.status_code, message, err.response.headers)
    elif isinstance(err, sdk.APIConnectionError):
        verdict = classify(None, str(err) or type(err).__name__)
    else:
        verdict = None
    if verdict is not None:
        raise verdict from err
    return Proposal(kind="invalid", error=f"api error: {error_text(str(err))}")


def _retry_after(headers: Mapping[str, str] | None) -> float | None:
    if not headers:
        return None
    for name, scale in (("retry-after-ms", 1e-3), ("retry-after", 1.0)):
        try:
            value = float(headers.get(name, "")) * scale
        except ValueError:
            continue
        if value >= 0:
            return value
    return None


def classify(status: int | None, message: str, headers: Mapping[str, str] | None = None) -> Exception | None:
    """What a failed call means; ``status`` None is a timeout or a connection error."""
    text = error_text(message)
    if status is None:
        return TransientAPIError(f"transport: {text}")
    if status == 402 or (status in (400, 403, 429) and SPEND_LIMIT.search(text)):
        return FatalAPIError(f"the provider refused for a spend limit ({status}): {text}", "spend_limit")
    if status in (401, 403):
        return FatalAPIError(f"the provider refused the credentials ({status}): {text}", "auth")
    if status in TRANSIENT_STATUS or status >= 500:
        return TransientAPIError(f"{status}: {text}", _retry_after(headers))
    return None


class RetryBudgetSpent(Exception):
    """The next retry would pass the campaign's wall-clock budget: the campaign ends on it."""


@dataclass(frozen=True)
class RetryPolicy:
    """Backoff ``base_s * 2**k``, or the server's retry-after when it sends one, capped at ``cap_s``;
    the faults of one call are retried for at most ``window_s`` seconds."""

    base_s: float = 2.0
    cap_s: float = 60.0
    window_s: float = 1800.0


def call_with_retries(
    call: Callable[[], Proposal],
    *,
    seconds_left: float | None = None,
    policy: RetryPolicy = RetryPolicy(),
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> Proposal:
    """``call()`` retried on :class:`TransientAPIError`; the faults go into the proposal's notes.

    Raises :class:`RetryBudgetSpent` when the next wait (or the server's retry-after) would pass
    ``seconds_left``, the campaign's remaining wall-clock budget; gives up as an invalid proposal
    after the policy's window. :class:`FatalAPIError` propagates.
    """
    start, faults = clock(), []
    while True:
        try:
            proposal = call()
        except TransientAPIError as err:
            hint = err.retry_after  # the server knows best when it will take the call again
            wait = min(policy.cap_s, policy.base_s * 2 ** len(faults) if hint is None else hint)
            faults.append(f"{err} (retry in {wait:.3g} s)")
            spent = clock() - start
            if seconds_left is not None and spent + max(wait, hint or 0.0) > seconds_left:
                raise RetryBudgetSpent(
                    f"the LLM API kept failing ({len(faults)} tries, last: {err}) and the next retry "
                    f"would pass the wall-clock budget"
                ) from err
            if spent + wait > policy.window_s:
                return Proposal(
                    kind="invalid",
                    error=f"transport faults outlasted the {policy.window_s:g} s retry window "
                    f"({len(faults)} tries): {err}",
                    notes={"transport_faults": faults},
                )
            sleep(wait)
            continue
        if faults and isinstance(proposal, Proposal):
            proposal = dataclasses.replace(proposal, notes={**proposal.notes, "transport_faults": faults})
        return proposal
