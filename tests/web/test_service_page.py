"""The service sends TECU_EstEfficiency and serves the page; the systemd unit allows exactly its socket."""

from __future__ import annotations

import asyncio
import json
import math
import re
from pathlib import Path

import can

from tractionecu.advice.bus import MESSAGE
from tractionecu.bus import j1939
from tractionecu.bus.dbc import default_codec
from tractionecu.service.config import ServiceConfig, WebConfig, with_overrides
from tractionecu.sim.player import run_simulation

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "tractionecu.service"


def test_simulated_run_sends_the_efficiency_message_and_serves_the_page(short_recording: Path, tmp_path: Path) -> None:
    codec = default_codec()
    listener: list[can.BusABC] = []

    def attach(machine) -> None:
        listener.append(can.Bus(interface="virtual", channel=machine.channel))

    cfg = with_overrides(ServiceConfig(), service={"state_dir": str(tmp_path / "state")},
                         estimation={"lag_s": 0.25, "max_catch_up_s": 5.0}, web={"port": 0, "update_hz": 5.0})

    res = asyncio.run(run_simulation(cfg, short_recording, speed=2.0, duration_s=10.0, before_play=attach))
    frames = []
    try:
        while (m := listener[0].recv(timeout=0)) is not None:
            frames.append(m)
    finally:
        listener[0].shutdown()
    assert res.exit_code == 0
    svc = res.service
    ours = [m for m in frames if m.arbitration_id & 0xFF == svc.network.address
            and j1939.pgn_of(m.arbitration_id) == codec.message(MESSAGE).pgn]
    assert len(ours) > 50                                   # 10 Hz over ~9 s of claimed address
    decoded = [codec.decode(m.arbitration_id, bytes(m.data))[1] for m in ours]
    assert all(0 <= int(v["EfficiencyValidity"]) < 32 for v in decoded)
    late = decoded[-10:]
    assert any(math.isfinite(v["TractionEfficiency"]) and 0.3 < v["TractionEfficiency"] < 1.0 for v in late)
    c = svc.counters()
    assert c["advice"]["fed"] > 50 and c["advice"].get("errors", 0) == 0
    assert c["web"]["address"] and c["web"].get("snapshot_errors", 0) == 0 and c["web"]["updates"] > 10
    state = json.loads(svc.web.last_json)
    assert state["health"]["can"] == "open" and "efficiency" in state and "estimate" in state


def test_systemd_unit_allows_exactly_the_page_socket() -> None:
    text = UNIT.read_text(encoding="utf-8")
    assert re.search(rf"^SocketBindAllow=tcp:{WebConfig().port}$", text, re.M)
    assert re.search(r"^SocketBindDeny=any$", text, re.M)
    assert re.search(r"^IPAddressAllow=localhost$", text, re.M) and re.search(r"^IPAddressDeny=any$", text, re.M)
    assert WebConfig().host == "127.0.0.1"
