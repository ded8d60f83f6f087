"""Audit test family export hook: writes the saved policy as the "file that flies" (called by the
audit report, as families/*/export.py writes ONNX)."""

import argparse
import json
from pathlib import Path

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--policy", required=True, help="a run's saved policy directory")
    parser.add_argument("--onnx", required=True, help="the file to write")
    args = parser.parse_args()
    policy = json.loads((Path(args.policy) / "policy.json").read_text())
    Path(args.onnx).write_text(json.dumps({"exported": policy}))
