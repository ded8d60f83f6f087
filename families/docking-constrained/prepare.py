"""Build (--warm-cache) or verify (--check) every data set this family's train.py can read.

    python prepare.py --warm-cache   # once, slow: expert solves for the whole pool
    python prepare.py --check        # seconds: exit 1 naming whatever is missing or inconsistent

The sets are stated here from train.py's own constants (so the two cannot disagree);
cwh_envs.prepare builds and verifies them.
"""

import sys

from cwh_envs.prepare import DataNeeds, import_train, main

# this directory's train.py: its constants (its run is guarded by __main__); the base install has no torch
train = import_train({"torch": "torch"}, "families")

NEEDS = DataNeeds(
    task=train.TASK,
    problem=train.PROBLEM,
    pool_demos=train.POOL_DEMOS,
    data_seed=train.DATA_SEED,
    n_eval=train.N_EVAL,
    n_test=train.N_TEST,
    obs_dim=train.OBS_DIM,
    pool_recovery=train.POOL_RECOVERY,
    expert_margins=train.EXPERT_MARGINS,
)

if __name__ == "__main__":
    sys.exit(main(NEEDS, __doc__))
