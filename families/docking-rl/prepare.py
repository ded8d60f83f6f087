"""Build (--warm-cache) or verify (--check) every data set this family's train.py can read.

    python prepare.py --warm-cache   # once: the expert solves of the two splits, and the start pool
    python prepare.py --check        # seconds: exit 1 naming whatever is missing or inconsistent

PPO learns from no demonstrations: a run reads the docking family's search and sealed test splits
(the starts it is scored on, with the expert's thrust the fuel is measured against) and the pool of
screened starts its training envs reset from. They are stated here from train.py's own constants
(so the two cannot disagree); cwh_envs.prepare builds and verifies them.
"""

import sys

from cwh_envs.prepare import DataNeeds, import_train, main

# this directory's train.py: its constants (its run is guarded by __main__); the base install has neither
train = import_train({"torch": "torch", "stable_baselines3": "stable-baselines3"}, "families,sb3")

NEEDS = DataNeeds(
    task=train.TASK,
    problem=train.PROBLEM,
    n_eval=train.N_EVAL,
    n_test=train.N_TEST,
    start_pool=train.START_POOL,
)

if __name__ == "__main__":
    sys.exit(main(NEEDS, __doc__))
