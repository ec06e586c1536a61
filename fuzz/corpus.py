"""Valid seed inputs for the harnesses.

Seeds come from two places: a short recording written by the project's own
simulator (``paper-three-soils``, 3 s: candump lines of every input PGN,
GGA/RMC/VTG at 10 Hz, ``vehicle.toml``) and the fixtures under
``tests/data`` (the real John Deere 5055E excerpt, the hand-written bad
candump lines, the u-blox NMEA examples).  CSV seeds are derived from the
simulated recording (contract columns), from the J1939-logger column names
and from the 5055E frames written back as PolyCAN rows.  Config seeds are
the defaults of each loader written as TOML.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEST_DATA = REPO / "tests" / "data"


@dataclass
class Seeds:
    """Seed material of every path (all plain strings, so it pickles cheaply)."""

    can_frames: list[tuple[int, bool, bytes]] = field(default_factory=list)
    candump_lines: list[str] = field(default_factory=list)
    nmea_lines: list[str] = field(default_factory=list)
    csv_contract_header: list[str] = field(default_factory=list)
    csv_contract_rows: list[list[str]] = field(default_factory=list)
    csv_logger_header: list[str] = field(default_factory=list)
    csv_logger_rows: list[list[str]] = field(default_factory=list)
    polycan_header: list[str] = field(default_factory=list)
    polycan_rows: list[list[str]] = field(default_factory=list)
    vehicle_toml: str = ""
    service_toml: str = ""
    estimator_toml: str = ""


def _lines(path: Path) -> list[str]:
    return [ln for ln in path.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]


def build_seeds(duration_s: float = 3.0) -> Seeds:
    """Simulate a short recording and collect the seeds (≈ 0.5 s)."""
    from tractionecu.bus import j1939
    from tractionecu.bus.candump import iter_candump
    from tractionecu.config import VehicleParams, to_toml
    from tractionecu.estimation.estimator import EstimatorConfig
    from tractionecu.recording.csv_import import CONTRACT_MAPPING, J1939_LOGGER_MAPPING
    from tractionecu.recording.reader import read_recording
    from tractionecu.service import config as service_config
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    s = Seeds()
    with tempfile.TemporaryDirectory(prefix="tecu-fuzz-seed-") as tmp:
        out = Path(tmp) / "rec"
        scn = scenarios.get("paper-three-soils", seed=3, duration_s=duration_s)
        write_recording(scn, simulate(scn), out)
        sim_can = _lines(out / "can.log")
        s.nmea_lines = _lines(out / "gps.nmea")
        s.vehicle_toml = (out / "vehicle.toml").read_text(encoding="utf-8")
        rec = read_recording(out)

    jd = _lines(TEST_DATA / "candump" / "jd5055e_excerpt.log")
    s.candump_lines = sim_can + jd + _lines(TEST_DATA / "candump" / "bad_lines.log")
    s.nmea_lines += _lines(TEST_DATA / "nmea" / "mixed.nmea")
    for f in iter_candump(sim_can + jd):
        s.can_frames.append((f.can_id, f.is_extended, f.data))

    # contract CSV: sparse cells, a value only where the signal has a new sample
    names = [n for n in CONTRACT_MAPPING.columns if n in rec.signals] + [
        f"gps_{k}" for k in ("lat", "lon", "alt", "speed", "course", "fix_quality", "hdop", "nsat")
    ]
    tab = rec.table(100.0)
    s.csv_contract_header = ["t"] + names
    for i, t in enumerate(tab.t):
        row = [f"{t:.3f}"]
        for n in names:
            key = n if n in tab else n
            v, age = tab.values[key][i], tab.age[key][i]
            row.append("" if not math.isfinite(v) or age > 0.0105 else f"{v:.6g}")
        s.csv_contract_rows.append(row)

    # J1939-logger CSV (asammdf style names with dots)
    s.csv_logger_header = ["timestamps"] + [k.replace("_", ".", 1) for k in J1939_LOGGER_MAPPING.columns]
    for i in range(200):
        t = 100.0 + 0.01 * i
        row = [f"{t:.2f}"]
        for k in J1939_LOGGER_MAPPING.columns:
            col = J1939_LOGGER_MAPPING.columns[k]
            if (i + len(k)) % 3:
                row.append("")
            elif col.target == "gps.lat":
                row.append(f"{45.5 + 1e-5 * i:.7f}")
            elif col.target == "gps.lon":
                row.append(f"{-111.0 + 1e-5 * i:.7f}")
            elif col.target == "gps.nsat":
                row.append(str(8 + i % 5))
            else:
                row.append(f"{(i * 7.3) % 100:.2f}")
        s.csv_logger_rows.append(row)

    # PolyCAN export rows rebuilt from the real 5055E frames and the simulated frames
    s.polycan_header = ["", "time", "pgn", "priority", "source", "destination", "data", "description"]
    t0 = None
    for n, f in enumerate(iter_candump(jd + sim_can[:200])):
        cid = j1939.parse_id(f.can_id) if f.is_extended else None
        if cid is None:
            continue
        t0 = f.t if t0 is None else t0
        s.polycan_rows.append([
            str(n), f"{(f.t - t0) * 1000.0:.3f}", str(cid.pgn), str(cid.priority), str(cid.sa),
            str(cid.da if cid.da is not None else 255), " ".join(f"{b:02X}" for b in f.data), "x",
        ])

    s.vehicle_toml = s.vehicle_toml or "[vehicle]\n" + to_toml(VehicleParams())
    s.estimator_toml = EstimatorConfig().to_toml()
    s.service_toml = service_config.to_toml(service_config.ServiceConfig()) + '\n[can.options]\nbitrate = 250000\n'
    return s
