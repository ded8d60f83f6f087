"""The subcommands of ``autoresearch``, one module each (``add_parser(subparsers)`` and
``run(args) -> int``). Their one-line summaries live here, so that ``autoresearch --help`` lists
every command without importing any: the modules pull in numpy, scipy, matplotlib and Optuna."""

# command -> module in this package, in the order ``autoresearch --help`` lists them
MODULES = {
    "init": "init",
    "loop": "loop",
    "noise": "noise",
    "verify": "verify",
    "prune": "prune",
    "random": "random_arm",
    "audit": "audit",
    "report": "report",
    "compare": "compare",
    "check": "check",
    "export": "export",
}

SUMMARIES = {
    "init": "write a new family directory from a template (minimal, docking, rendezvous)",
    "loop": "run the agent loop on a family (one campaign)",
    "noise": "measure a family's seed noise: its baseline over K fresh seeds",
    "verify": "reseed a campaign's top configurations at fresh seeds and promote the family best",
    "prune": "find which edits of the promoted configuration carry the result",
    "random": "run random search over the same surface and budget as a campaign",
    "audit": "noise, verify, prune and the random arm for one campaign, then report.md",
    "report": "write report.md and its figures into a campaign directory",
    "compare": "compare arms over their repeated campaigns (median, IQM, P(better), target)",
    "check": "validate a family against the contract, or a campaign's files (and say how to repair them)",
    "export": "write a campaign to an Optuna journal file (optuna-dashboard, Optuna's plots)",
}
