"""The agent loop of one campaign (paper Algorithm 1): orchestrator, scheduler, stopping rules, the
proposer's context, the live view, a campaign's session, and a group's repeats. It runs its
experiments through autoresearch.execution and records them through autoresearch.campaign."""
