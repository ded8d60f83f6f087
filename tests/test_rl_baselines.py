"""benchmarks/rl_baselines.py (issue 60): seeds train to the budget, a stopped run resumes from its
last checkpoint, the row is scored on the sealed split and summarised by rliable's IQM."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import rl_baselines

pytestmark = pytest.mark.needs("rl", "families")


def run(tmp_path, *args, task="docking"):
    rl_baselines.main(
        ["--task", task, "--work", str(tmp_path / "work"), "--out", str(tmp_path / "out"), *args]
    )
    label = args[args.index("--algo") + 1] + (f"-{args[args.index('--tag') + 1]}" if "--tag" in args else "")
    return json.loads((tmp_path / "out" / task / f"{label}.json").read_text())


def test_two_seeds_give_per_seed_sealed_scores_an_iqm_inside_them_and_curves(tmp_path):
    result = run(
        tmp_path, "--algo", "ppo", "--seeds", "0", "1", "--timesteps", "256", "--eval-every", "128", "--smoke"
    )
    assert result["seeds"] == [0, 1] and result["split"] == "test" and result["env_steps"] == 256
    low, high = min(result["metric_per_seed"]), max(result["metric_per_seed"])
    assert low <= result["iqm"]["iqm"] <= high
    assert result["iqm"]["ci95"][0] <= result["iqm"]["iqm"] <= result["iqm"]["ci95"][1]
    for curve in result["curves"]:
        steps = [p["timesteps"] for p in curve["curve"]]
        assert steps == sorted(steps) and steps[-1] >= 256
    assert (tmp_path / "out" / "docking" / "ppo_curves.png").stat().st_size > 0


def test_a_longer_budget_resumes_each_seed_from_its_checkpoint(tmp_path):
    first = run(
        tmp_path, "--algo", "ppo", "--seeds", "0", "--timesteps", "128", "--eval-every", "128", "--smoke"
    )
    again = run(
        tmp_path, "--algo", "ppo", "--seeds", "0", "--timesteps", "384", "--eval-every", "128", "--smoke"
    )
    before, after = first["curves"][0]["curve"], again["curves"][0]["curve"]
    assert after[: len(before)] == before  # the points already scored are kept, not retrained
    assert after[-1]["timesteps"] >= 384 and len(after) > len(before)
    log = (tmp_path / "work" / "docking" / "ppo" / "s0" / "curve.jsonl").read_text().splitlines()
    assert [json.loads(line) for line in log] == after


def test_sac_trains_scores_and_resumes_with_its_replay_buffer(tmp_path):
    common = ["--algo", "sac", "--seeds", "0", "--eval-every", "128", "--smoke"]
    first = run(tmp_path, *common, "--timesteps", "256")
    assert first["env_steps"] == 256 and len(first["metric_per_seed"]) == 1
    work = tmp_path / "work" / "docking" / "sac" / "s0"
    again = run(tmp_path, *common, "--timesteps", "384")
    assert again["curves"][0]["curve"][: len(first["curves"][0]["curve"])] == first["curves"][0]["curve"]
    args = rl_baselines.parse_args(["--task", "docking", "--algo", "sac", "--smoke"])
    row = rl_baselines.Row(args)
    model, _ = row.load(work, row.envs(0, 1))
    # every transition of the 384 steps, the 256 before the resume included, is in the saved buffer
    assert model.num_timesteps == 384 and model.replay_buffer.size() == 384


def test_residual_ppo_flies_the_law_plus_its_bounded_correction(tmp_path):
    args = rl_baselines.parse_args(
        ["--task", "docking", "--algo", "residual-ppo", "--smoke", "--residual-scale", "0.1"]
    )
    row = rl_baselines.Row(args)
    law = row.base()

    class Fixed:  # a trained model's predict: the correction it would fly
        def predict(self, obs, deterministic):
            return np.full((len(obs), 3), 5.0, dtype=np.float32), None

    class Identity:
        def normalize_obs(self, obs):
            return obs

    policy = row.policy(Fixed(), Identity())
    obs = np.tile(np.r_[30.0, -20.0, 10.0, 0.0, 0.0, 0.0, 8.0, 0.0, 0.0, 1.0], (2, 1))
    np.testing.assert_allclose(policy(obs), np.clip(law(obs) + 0.1, -1, 1))


def test_bad_arguments_are_refused(capsys):
    for bad, named in (
        (["--algo", "a2c"], "a2c"),
        (["--algo", "ppo", "--timesteps", "0"], "--timesteps"),
        (["--algo", "ppo", "--reward", "terminal_weight"], "'terminal_weight'"),
        (["--algo", "ppo", "--reward", "terminal_weight=ten"], "'terminal_weight=ten'"),
        (["--algo", "ppo", "--tag", "a/b"], "--tag"),
    ):
        with pytest.raises(SystemExit):
            rl_baselines.parse_args(["--task", "docking", *bad])
        assert named in capsys.readouterr().err
    # A weight the env does not have is the env's clear error, naming it and the weights it has.
    args = rl_baselines.parse_args(
        ["--task", "docking", "--algo", "ppo", "--smoke", "--reward", "precision=1"]
    )
    with pytest.raises(ValueError, match="precision"):
        rl_baselines.Row(args).envs(0, 1)


def test_a_tagged_recipe_trains_with_its_reward_weights_and_log_std_apart_and_is_resumed_only_as_asked(
    tmp_path,
):
    """--reward reaches the training env, --log-std-init the policy; the row is kept under its tag
    beside the algo's defaults, records its recipe, and a checkpoint resumed with another is refused."""
    from stable_baselines3 import PPO

    recipe = ["--reward", "terminal_weight=5", "effort_weight=0", "--log-std-init", "-4", "--tag", "precise"]
    common = ["--algo", "residual-ppo", "--seeds", "0", "--eval-every", "128", "--smoke"]
    result = run(tmp_path, *common, "--timesteps", "128", *recipe)
    assert result["tag"] == "precise" and result["log_std_init"] == -4.0
    assert result["reward"] == {"terminal_weight": 5.0, "effort_weight": 0.0}
    first = result["curves"][0]["curve"][0]
    assert first["reward"] == result["reward"] and first["log_std_init"] == -4.0
    work = tmp_path / "work" / "docking" / "residual-ppo-precise" / "s0"
    model = PPO.load(work / "model.zip", device="cpu")
    assert model.policy.log_std.detach().numpy() == pytest.approx(
        -4.0, abs=0.05
    )  # 128 steps move it a little
    args = rl_baselines.parse_args(["--task", "docking", "--algo", "residual-ppo", "--smoke", *recipe])
    env = rl_baselines.Row(args).envs(0, 1)
    while hasattr(env, "venv"):
        env = env.venv
    weights = env.env.unwrapped.reward_weights
    assert (weights.terminal_weight, weights.effort_weight, weights.success_bonus) == (5.0, 0.0, 10.0)
    assert not (tmp_path / "work" / "docking" / "residual-ppo").exists()  # the defaults' row untouched
    with pytest.raises(SystemExit, match="asked for the defaults"):
        run(tmp_path, *common, "--timesteps", "256", "--tag", "precise")
    again = run(tmp_path, *common, "--timesteps", "256", *recipe)  # the same recipe resumes
    assert again["curves"][0]["curve"][:2] == result["curves"][0]["curve"]


@pytest.mark.parametrize("task", ["docking", "docking-constrained"])
def test_residual_ppo_starts_as_the_law_and_every_curve_starts_before_learning(tmp_path, task):
    args = ["--algo", "residual-ppo", "--seeds", "0", "--timesteps", "128", "--eval-every", "128", "--smoke"]
    result = run(tmp_path, *args, task=task)
    first = result["curves"][0]["curve"][0]
    assert first["timesteps"] == 0 and first["train_seconds"] == 0.0
    row = rl_baselines.Row(rl_baselines.parse_args(["--task", task, "--algo", "residual-ppo", "--smoke"]))
    evaluate = row.eval_set("search", dispersed=False)
    law = evaluate(rl_baselines._Act(row.base()))
    assert first["metric"] == law[row.family.METRIC]  # a zero correction: the law to the bit
    assert first["success_rate"] == law["success_rate"]


def test_the_iqm_interval_is_the_same_on_every_summary():
    scores = [0.12, 0.10, 0.052, 0.062, 0.087]
    first, again = rl_baselines.iqm_interval(scores), rl_baselines.iqm_interval(scores)
    assert first == again
    assert first["ci95"][0] < first["iqm"] < first["ci95"][1]


def test_cloning_initialised_ppo_warms_its_critic_with_the_clone_held_as_it_was_fitted(tmp_path):
    """bc-ppo: during the critic warm-up the actor is frozen and VecNormalize's observation statistics
    stay the demonstrations' (FixedStatistics), so the policy after it flies exactly as the clone did;
    after it, PPO moves the actor. A checkpoint of another warm-up is refused, not resumed."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from cwh_envs.sb3 import FixedStatistics

    common = ["--algo", "bc-ppo", "--seeds", "0", "--eval-every", "128", "--smoke", "--bc-epochs", "1"]
    result = run(tmp_path, *common, "--timesteps", "256", "--critic-warmup", "128")
    clone, warmed, tuned = result["curves"][0]["curve"]
    assert (clone["timesteps"], warmed["timesteps"]) == (0, 128) and tuned["timesteps"] >= 256
    assert clone["critic_warmup"] == 128
    assert (warmed["metric"], warmed["success_rate"]) == (clone["metric"], clone["success_rate"])
    assert tuned["metric"] != clone["metric"]  # the actor learns once the warm-up is over
    work = tmp_path / "work" / "docking" / "bc-ppo" / "s0"
    row = rl_baselines.Row(rl_baselines.parse_args(["--task", "docking", "--algo", "bc-ppo", "--smoke"]))
    stats = VecNormalize.load(str(work / "vecnormalize.pkl"), row.envs(0, 1)).obs_rms
    assert isinstance(stats, FixedStatistics)
    before = stats.mean.copy()
    stats.update(np.ones((4, len(before))))
    np.testing.assert_array_equal(stats.mean, before)
    assert PPO.load(work / "model.zip", device="cpu").num_timesteps == tuned["timesteps"]
    with pytest.raises(SystemExit, match=r"trained with \{'critic_warmup': 128\}, asked for the defaults"):
        run(tmp_path, *common, "--timesteps", "384", "--critic-warmup", "0")


def test_an_annealed_learning_rate_falls_to_zero_over_the_whole_budget_not_over_each_curve_point(tmp_path):
    """--lr-anneal: SB3's own progress restarts at every learn() call (one per curve point, and on
    resuming), so a plain linear schedule would reach 0 at every point; the row's reaches it once, at
    the budget, and a checkpoint trained with it resumes with it and is refused without it."""
    from stable_baselines3 import PPO

    common = ["--algo", "ppo", "--seeds", "0", "--eval-every", "128", "--smoke", "--tag", "lin"]
    result = run(tmp_path, *common, "--timesteps", "128", "--lr-anneal")
    assert result["lr_anneal"] is True and result["curves"][0]["curve"][0]["lr_anneal"] is True
    with pytest.raises(SystemExit, match="asked for the defaults"):
        run(tmp_path, *common, "--timesteps", "256")
    again = run(tmp_path, *common, "--timesteps", "256", "--lr-anneal")  # loads the pickled schedule
    assert again["curves"][0]["curve"][:2] == result["curves"][0]["curve"]

    row = rl_baselines.Row(rl_baselines.parse_args(["--task", "docking", "--algo", "ppo", "--smoke"]))
    model = PPO("MlpPolicy", row.envs(0, 2), n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
    rates = []
    for chunk in (128, 128):  # two rollouts of 2 x 64 steps: one update each, at step 128 and 256
        rl_baselines.anneal(model, 1e-3, 256, chunk)
        model.learn(chunk, reset_num_timesteps=False)
        rates.append(model.policy.optimizer.param_groups[0]["lr"])
    assert rates == pytest.approx([5e-4, 0.0])


def test_a_learning_rate_set_for_a_row_trains_at_it_and_is_part_of_its_recipe(tmp_path):
    """--learning-rate (cloning-initialised PPO's next probe: a rate two orders below the zoo's, so that
    PPO's updates keep the actor near the clone): the optimiser runs at it, the curve records it and a
    checkpoint trained at it is refused for another rate."""
    from stable_baselines3 import PPO

    common = ["--algo", "ppo", "--seeds", "0", "--eval-every", "128", "--smoke", "--tag", "lr"]
    result = run(tmp_path, *common, "--timesteps", "128", "--learning-rate", "1e-5")
    assert result["curves"][0]["curve"][0]["learning_rate"] == 1e-5
    model = PPO.load(tmp_path / "work" / "docking" / "ppo-lr" / "s0" / "model.zip", device="cpu")
    assert model.policy.optimizer.param_groups[0]["lr"] == pytest.approx(1e-5)
    with pytest.raises(SystemExit, match="asked for the defaults"):
        run(tmp_path, *common, "--timesteps", "256")
    for bad in ("0", "-1e-4", "nan"):
        with pytest.raises(SystemExit):
            rl_baselines.parse_args(["--task", "docking", "--algo", "ppo", "--learning-rate", bad])


def test_the_cloning_term_adds_its_decaying_gradient_to_each_ppo_step_and_is_part_of_the_recipe(tmp_path):
    """--bc-weight (DAPG's augmented gradient): before each of PPO's optimiser steps the hook adds
    exactly ``weight * decay**k`` times the clone's loss gradient on a demonstration minibatch to the
    gradient PPO left, ``k`` the PPO iteration from the env steps (so a resumed run continues the
    schedule); nothing while the actor is frozen; the recipe records it and refuses another."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    row = rl_baselines.Row(rl_baselines.parse_args(["--task", "docking", "--algo", "bc-ppo", "--smoke"]))
    normalizer = VecNormalize(row.envs(0, 2))
    model = PPO("MlpPolicy", normalizer, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    rl_baselines.clone_into(model, normalizer, row.family, 1, 0)
    rl_baselines.cloning_term(model, normalizer, row.family, 0.5, 0.5, seed=7)
    obs, actions = rl_baselines.demonstration_pairs(row.family)
    x = torch.as_tensor(normalizer.normalize_obs(obs), dtype=torch.float32)
    y = torch.as_tensor(actions, dtype=torch.float32)
    batch = torch.randint(len(x), (32,), generator=torch.Generator().manual_seed(7))  # the hook's first draw
    params = list(model.policy.parameters())
    model.policy.optimizer.zero_grad()
    (0.5 * 0.5**3 * rl_baselines.cloning_loss(model.policy, x[batch], y[batch])).backward()
    expected = [torch.zeros_like(p) if p.grad is None else p.grad.clone() for p in params]
    assert any(e.abs().sum() > 0 for e in expected)
    for group in model.policy.optimizer.param_groups:
        group["lr"] = (
            0.0  # the step then leaves the parameters, and the gradients the hook added, as they are
        )
    model.num_timesteps = 3 * 128 + 5  # the 4th rollout of 2 envs x 64 steps: k = 3
    for p in params:
        p.grad = torch.ones_like(p)  # what PPO's own loss left
    model.policy.optimizer.step()
    for p, e in zip(params, expected, strict=True):
        torch.testing.assert_close(p.grad, 1.0 + e)
    for p in rl_baselines.actor_parameters(model):  # the critic's warm-up: the actor frozen, no term
        p.requires_grad_(False)
    for p in params:
        p.grad = torch.ones_like(p)
    model.policy.optimizer.step()
    assert all(torch.equal(p.grad, torch.ones_like(p)) for p in params)

    common = ["--algo", "bc-ppo", "--seeds", "0", "--eval-every", "128", "--smoke", "--bc-epochs", "1"]
    common += ["--critic-warmup", "0", "--tag", "dapg"]
    result = run(tmp_path, *common, "--timesteps", "128", "--bc-weight", "0.1", "--bc-decay", "0.9")
    assert (result["bc_weight"], result["bc_decay"]) == (0.1, 0.9)
    assert result["curves"][0]["curve"][0]["bc_weight"] == 0.1
    with pytest.raises(SystemExit, match="asked for the defaults"):
        run(tmp_path, *common, "--timesteps", "256")
    for bad in (["--bc-weight", "-1"], ["--bc-weight", "nan"], ["--bc-decay", "0"], ["--bc-decay", "1.5"]):
        with pytest.raises(SystemExit):
            rl_baselines.parse_args(["--task", "docking", "--algo", "bc-ppo", *bad])
    with pytest.raises(SystemExit):  # only bc-ppo has a clone to keep
        rl_baselines.parse_args(["--task", "docking", "--algo", "ppo", "--bc-weight", "0.1"])
