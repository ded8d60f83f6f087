"""A campaign directory and its format, owned in one place (as Optuna's storage owns its schema).

```
<campaign>/
  campaign.json      CampaignMeta: the family (and where it is), the proposer, the settings, the sessions
  family.json        the campaign's copy of the family registry, with its running best (campaign_best)
  proposals.jsonl    one Record per iteration, whatever happened (schema 2; schema 1 reads too)
  runs.jsonl         the runs' FINAL_METRIC lines (train.py appends them through --runs-log)
  runs/<run_id>/     intent.json (the record-to-be), the patched train.py, stdout, result.json, out/
  audit.json         the audit's parts, one per step (audit_log.py)
  audit/<step>/      each step's log of trials (audit_log.TrialRow) and its runs
  campaign.lock      held by the one process that writes the campaign (lock.py)
```

- records.py: Record and Status, the one record type, and the schema.
- meta.py: campaign.json.
- state.py: CampaignState, the fold over the records that the loop decides on.
- store.py: Campaign, the one reader and writer, and CampaignWriter, the loop's write path.
- audit_log.py: audit.json and the audit steps' logs, typed (TrialRow).
- lock.py: one process at a time writes a campaign.
- group.py: a group of repeats (repeats.json, repeat-NN/ campaigns).
- check.py: what ``autoresearch check`` validates, and how to repair it.
"""

from autoresearch.campaign.meta import CampaignMeta, portable_path, session
from autoresearch.campaign.paths import CampaignError, CampaignPaths
from autoresearch.campaign.records import BASELINE_PROPOSER, RUN_STATUSES, TERMINAL, Record, Status, now
from autoresearch.campaign.state import CampaignState, count_iterations
from autoresearch.campaign.store import Campaign, CampaignWriter, Intent

__all__ = [
    "BASELINE_PROPOSER",
    "RUN_STATUSES",
    "TERMINAL",
    "Campaign",
    "CampaignError",
    "CampaignMeta",
    "CampaignPaths",
    "CampaignState",
    "CampaignWriter",
    "Intent",
    "Record",
    "Status",
    "count_iterations",
    "now",
    "portable_path",
    "session",
]
