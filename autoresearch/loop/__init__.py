"""The agent loop of one campaign (paper Algorithm 1): orchestrator, campaign records, runner, stopping rules, verdicts, live view."""
