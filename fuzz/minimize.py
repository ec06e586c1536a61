"""Shrink a failing case to a small one that fails the same way (same signature).

Usage, from the repository root::

    python fuzz/minimize.py fuzz/crashes/nmea-XXXX.json [OUT.json]

The case's lists (CAN frames, NMEA lines) or file lines are removed in
halves, then one by one, as long as the failure keeps its signature
(kind, exception type and the project line it was raised at).
"""

from __future__ import annotations

import json
import logging
import random
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from fuzz.corpus import build_seeds  # noqa: E402
from fuzz.run import _where  # noqa: E402
from fuzz.targets import TARGETS, ContractViolation, _b64, _unb64  # noqa: E402


def signature(target, case) -> str | None:
    """The failure signature of ``case``, or None if it passes."""
    try:
        target.run(case)
    except ContractViolation as e:
        return f"violation: {type(e).__name__} at {_where(e)}"
    except Exception as e:  # noqa: BLE001
        return f"unhandled: {type(e).__name__} at {_where(e)}"
    return None


def _ddmin(items: list, fails) -> list:
    n = 2
    while len(items) >= 2:
        chunk = max(1, len(items) // n)
        for i in range(0, len(items), chunk):
            trial = items[:i] + items[i + chunk:]
            if trial and fails(trial):
                items = trial
                n = max(n - 1, 2)
                break
        else:
            if chunk == 1:
                break
            n = min(len(items), 2 * n)
    return items


def minimize(rec: dict) -> dict:
    path = rec["path"]
    with tempfile.TemporaryDirectory() as tmp:
        target = TARGETS[path](build_seeds(), random.Random(0), Path(tmp))
        case = target.load(rec["case"])
        want = signature(target, case)
        if want is None:
            raise SystemExit("the case does not fail (any more)")

        def with_items(items):
            c = dict(case)
            if path == "can":
                c["frames"] = items
            elif path == "nmea":
                c["lines"] = [x for x, _ in items]
                c["terms"] = [t for _, t in items]
            else:
                key = "can.log" if path == "candump" else "file"
                sub = getattr(with_items, "sub", key)
                c[sub] = b"".join(items)
            return c

        def fails(items):
            return signature(target, with_items(items)) == want

        if path == "can":
            case = with_items(_ddmin(list(case["frames"]), fails))
        elif path == "nmea":
            case = with_items(_ddmin(list(zip(case["lines"], case["terms"])), fails))
        else:
            subs = ["can.log", "gps.nmea"] if path == "candump" else ["file"]
            for sub in subs:
                if case.get(sub) is None:
                    continue
                with_items.sub = sub
                lines = case[sub].splitlines(keepends=True)
                case = with_items(_ddmin(lines, fails))
        out = dict(rec)
        out["case"] = target.dump(case)
        out["signature"] = want
        out.pop("traceback", None)
        return out


if __name__ == "__main__":
    logging.disable(logging.CRITICAL)
    src = Path(sys.argv[1])
    res = minimize(json.loads(src.read_text(encoding="utf-8")))
    text = json.dumps(res, indent=1) + "\n"
    if len(sys.argv) > 2:
        Path(sys.argv[2]).write_text(text, encoding="utf-8")
    print(text)
