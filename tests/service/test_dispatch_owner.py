"""The live dispatch: J1939-21 transport-protocol reassembly, the owner's DBC through can.dbc and [signals],
and an engine-driven machine's estimator, with python-can virtual buses (no SocketCAN)."""

from __future__ import annotations

import math
from pathlib import Path

import can
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.dbc import default_codec
from tractionecu.bus.transport import CM_BAM, PGN_TP_CM, PGN_TP_DT, TRANSPORT_PGNS
from tractionecu.config import DrivetrainSpec, VehicleParams, save_vehicle
from tractionecu.errors import ConfigError
from tractionecu.estimation.machine import MachineEstimator
from tractionecu.pipeline.gnss import GnssGate
from tractionecu.pipeline.signals import MACHINE_GROUPS
from tractionecu.pipeline.steps import StepAssembler
from tractionecu.service.config import ServiceConfig, from_dict, with_overrides
from tractionecu.service.daemon import Service
from tractionecu.service.dispatch import FrameDispatcher, codec_for
from tractionecu.service.fixes import FixBuffer
from tractionecu.service.loop import default_estimator_factory, estimator_groups, warm_up

CODEC = default_codec()
EC1 = 65251

OWNER_DBC = """VERSION ""

NS_ :

BS_:

BU_: DriveCtrl TractionECU

BO_ 2365583104 DriveCtrl_3: 8 DriveCtrl
 SG_ WhlSpdFL : 0|16@1+ (0.01,0) [0|600] "rpm" TractionECU
 SG_ WhlSpdFR : 16|16@1+ (0.01,0) [0|600] "rpm" TractionECU
 SG_ WhlSpdRL : 32|16@1+ (0.01,0) [0|600] "rpm" TractionECU
 SG_ WhlSpdRR : 48|16@1+ (0.01,0) [0|600] "rpm" TractionECU
"""
"""An owner's message: PGN 0xFF40 (proprietary B) from SA 0x00, wheel speeds in rpm."""

RPM = 2 * math.pi / 60


def bam_frames(sa: int, pgn: int, payload: bytes) -> list[can.Message]:
    packets = (len(payload) + 6) // 7
    out = [can.Message(arbitration_id=j1939.make_id(7, PGN_TP_CM, sa, 0xFF),
                       data=bytes([CM_BAM, len(payload) & 0xFF, len(payload) >> 8, packets, 0xFF])
                       + pgn.to_bytes(3, "little"))]
    for k in range(packets):
        out.append(can.Message(arbitration_id=j1939.make_id(7, PGN_TP_DT, sa, 0xFF),
                               data=bytes([k + 1]) + payload[7 * k:7 * k + 7].ljust(7, b"\xff")))
    return out


def through_virtual_bus(frames: list[can.Message]) -> list[can.Message]:
    """Send frames on one python-can virtual bus and read them from another on the same channel."""
    tx = can.Bus(interface="virtual", channel="mech-dispatch", receive_own_messages=False)
    rx = can.Bus(interface="virtual", channel="mech-dispatch")
    try:
        for f in frames:
            tx.send(f)
        got = []
        for _ in frames:
            m = rx.recv(timeout=1.0)
            assert m is not None
            got.append(m)
        return got
    finally:
        tx.shutdown()
        rx.shutdown()


def ec1_payload(ref_nm: float) -> bytes:
    _, data = CODEC.encode("EC1", {"EngineReferenceTorque": ref_nm, "EngineSpeedAtIdlePoint1": 80.0})
    return data


def test_ec1_by_bam_reaches_the_machine_estimator_steps() -> None:
    steps = StepAssembler(groups=MACHINE_GROUPS)
    d = FrameDispatcher(CODEC, steps, FixBuffer(GnssGate()))
    for k, m in enumerate(through_virtual_bus(bam_frames(0x00, EC1, ec1_payload(410.0)))):
        d.on_frame(1.0 + 0.05 * k, m)
    inputs, _ = steps.take(2.0)
    assert inputs["Tref"] == pytest.approx(410.0)
    assert d.stats["tp_frames"] == 7 and d.stats["tp_messages"] == 1 and d.stats["rx_EC1"] == 1


def test_tp_sessions_time_out_and_are_bounded() -> None:
    d = FrameDispatcher(CODEC, StepAssembler(groups=MACHINE_GROUPS), FixBuffer(GnssGate()))
    frames = bam_frames(0x00, EC1, ec1_payload(410.0))
    d.on_frame(0.0, frames[0])
    for k, m in enumerate(frames[1:]):
        d.on_frame(1.0 + 0.01 * k, m)                     # packets 1 s after the announcement: T1 expired
    assert d.stats["tp_messages"] == 0 and d.tp.dropped == 1
    for sa in range(200):                                  # announcements that never finish
        d.on_frame(2.0, bam_frames(sa, EC1, ec1_payload(1.0))[0])
    assert d.tp.open_sessions <= d.tp.max_sessions


def test_owner_dbc_and_signals_table_feed_the_contract_names(tmp_path: Path) -> None:
    dbc = tmp_path / "owner.dbc"
    dbc.write_text(OWNER_DBC, encoding="utf-8")
    cfg = from_dict({"can": {"dbc": [str(dbc)]},
                     "signals": {f"WheelSpeed_{w}": {"signal": f"DriveCtrl_3.WhlSpd{w}", "scale": RPM}
                                 for w in ("FL", "FR", "RL", "RR")}})
    codec, mapping = codec_for(cfg)
    assert [m[0] for m in mapping] == ["WheelSpeed_FL", "WheelSpeed_FR", "WheelSpeed_RL", "WheelSpeed_RR"]
    steps = StepAssembler()
    d = FrameDispatcher(codec, steps, FixBuffer(GnssGate()), mapping=mapping)
    cid, data = codec.encode("DriveCtrl_3", {f"DriveCtrl_3.WhlSpd{w}": 30.0 + i for i, w in
                                             enumerate(("FL", "FR", "RL", "RR"))}, sa=0x27)
    (m,) = through_virtual_bus([can.Message(arbitration_id=cid, data=data)])
    d.on_frame(5.0, m)
    _, meas = steps.take(5.1)
    assert list(meas["omega"]) == pytest.approx([(30.0 + i) * RPM for i in range(4)])
    assert steps.anchor == pytest.approx(5.0, abs=0.01)        # the mapped wheel speed phases the grid


def test_signals_table_errors_name_the_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="signals.WheelSpeed_FL"):
        codec_for(from_dict({"signals": {"WheelSpeed_FL": "NoSuchMessage.X"}}))
    with pytest.raises(ConfigError, match="signals.Bogus"):
        codec_for(from_dict({"signals": {"Bogus": "EEC1.EngineSpeed"}}))
    with pytest.raises(ConfigError, match="signals.WheelSpeed_FL.scale"):
        from_dict({"signals": {"WheelSpeed_FL": {"signal": "EEC1.EngineSpeed", "scale": 0}}})


def test_a_signals_error_of_the_vehicle_file_names_that_file(tmp_path: Path) -> None:
    """The service reads [signals] from its config and from the vehicle file; an error in the vehicle file's said
    "signals.WheelSpeed_FL: ..." and named neither file."""
    veh = tmp_path / "vehicle.toml"
    veh.write_text('[vehicle]\nmass_kg = 6300.0\n[signals]\nWheelSpeed_FL = "NoSuchMessage.X"\n', encoding="utf-8")
    with pytest.raises(ConfigError) as ei:
        codec_for(from_dict({"estimation": {"vehicle": str(veh)}}))
    assert str(ei.value).startswith(f"{veh}: signals.WheelSpeed_FL: no message 'NoSuchMessage'"), str(ei.value)
    # the service config's own key over it: its error is the config's, not the vehicle file's
    with pytest.raises(ConfigError) as ei:
        codec_for(from_dict({"estimation": {"vehicle": str(veh)}, "signals": {"WheelSpeed_FL": "Other.X"}}))
    assert str(ei.value).startswith("signals.WheelSpeed_FL: no message 'Other'"), str(ei.value)
    veh.write_text('[vehicle]\nmass_kg = 6300.0\n[signals]\nWheelSpeed_FL = ["x"]\n', encoding="utf-8")
    with pytest.raises(ConfigError) as ei:
        codec_for(from_dict({"estimation": {"vehicle": str(veh)}}))
    assert str(ei.value).startswith(f"{veh}: signals.WheelSpeed_FL: expected"), str(ei.value)


def mech_vehicle_file(tmp_path: Path) -> Path:
    p = tmp_path / "vehicle.toml"
    save_vehicle(VehicleParams(drivetrain=DrivetrainSpec(kind="mechanical", final_drive_ratio=20.0,
                                                         draft_sensing=False)), p)
    return p


def test_a_mechanical_vehicle_runs_the_machine_estimator_in_the_service(tmp_path: Path) -> None:
    cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, estimation={"vehicle": str(mech_vehicle_file(tmp_path))},
                         service={"state_dir": str(tmp_path / "state")})
    assert estimator_groups(cfg) is MACHINE_GROUPS
    svc = Service(cfg, env={}, warm_up_estimator=False)
    est = svc.estimation.build_estimator()
    assert isinstance(est, MachineEstimator) and not est.draft
    assert warm_up(default_estimator_factory, *svc.estimation.machine) > 0
    # EEC1 frames phase the grid and reach the estimator's keys
    cid, data = CODEC.encode("EEC1", {"EngineSpeed": 210.0, "ActualEnginePercentTorque": 55.0}, sa=0x00)
    svc.dispatcher.on_frame(3.0, can.Message(arbitration_id=cid, data=data))
    assert svc.steps.anchor == pytest.approx(3.0, abs=0.01)
    inputs, meas = svc.steps.take(3.01)
    assert inputs["Te"] == 55.0 and meas["we"] == pytest.approx(210.0, abs=0.02)
    e = est.step(3.01, inputs, meas)
    assert e.status & 0x4000 and math.isnan(e.rho_s)


def test_kernel_filters_pass_the_transport_protocol() -> None:
    from tractionecu.service.daemon import pgn_filters

    f = pgn_filters([*CODEC.pgns(), *TRANSPORT_PGNS], 0x90)
    cid = j1939.make_id(7, PGN_TP_DT, 0x00, 0xFF)
    assert any((cid & x["can_mask"]) == (x["can_id"] & x["can_mask"]) for x in f)


def test_an_owner_message_on_an_11_bit_identifier_feeds_the_steps(tmp_path: Path) -> None:
    """A CANedge GNSS speed frame (11-bit identifier 7, CSS Electronics' gnss.dbc layout) mapped onto the
    ground speed; before, every 11-bit frame was counted as ``standard_id_frames`` and dropped, and the
    kernel filters did not pass it."""
    from tractionecu.service.daemon import pgn_filters

    dbc = tmp_path / "gnss.dbc"
    dbc.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: X\nBO_ 7 gnss_speed: 5 X\n'
                   ' SG_ Speed : 1|20@1+ (0.001,0) [0|1048.575] "m/s" X\n'
                   ' SG_ SpeedValid : 0|1@1+ (1,0) [0|1] "" X\n', encoding="utf-8")
    cfg = from_dict({"can": {"dbc": [str(dbc)]}, "signals": {"GroundBasedMachineSpeed": "gnss_speed.Speed"}})
    codec, mapping = codec_for(cfg)
    steps = StepAssembler(groups=MACHINE_GROUPS)
    d = FrameDispatcher(codec, steps, FixBuffer(GnssGate()), mapping=mapping)
    raw = (2512 << 1) | 1                                     # 2.512 m/s, valid
    frames = [can.Message(arbitration_id=7, is_extended_id=False, data=raw.to_bytes(5, "little")),
              can.Message(arbitration_id=9, is_extended_id=False, data=bytes(8))]     # in no DBC
    for m in through_virtual_bus(frames):
        d.on_frame(4.0, m)
    assert d.stats["rx_gnss_speed"] == 1 and d.stats["standard_id_frames"] == 1
    d.on_frame(4.0, can.Message(arbitration_id=7, is_extended_id=False, data=bytes(8)))   # wrong length
    assert d.bad_frames["gnss_speed"] == 1
    _, meas = steps.take(4.01)
    assert meas["vr"] == pytest.approx(2.512)                 # the estimator's ground-speed key
    f = pgn_filters([*codec.pgns(), *TRANSPORT_PGNS], 0x90, codec.std_ids())
    assert {"can_id": 7, "can_mask": 0x7FF, "extended": False} in f
    assert all(x["extended"] for x in pgn_filters(CODEC.pgns(), 0x90, CODEC.std_ids()))


def test_a_late_gnss_epoch_is_named_by_the_status_lines_time(caplog):
    """The warning printed the epoch's raw POSIX time ('GNSS epoch 1783670401.432 arrived ...') while every
    status line counts t from the grid's start."""
    import logging

    from tractionecu.service.gps import GpsSample

    steps = StepAssembler()
    d = FrameDispatcher(CODEC, steps, FixBuffer(GnssGate()), lag_s=0.05)
    t0 = 1_783_670_400.0
    steps.push_signals(t0, {f"WheelSpeed_{w}": 3.0 for w in ("FL", "FR", "RL", "RR")})
    steps.take(t0 + 12.5)                                   # the loop has stepped to t0 + 12.5 s
    caplog.set_level(logging.WARNING, logger="tractionecu.service.dispatch")
    d.on_fix(GpsSample(t0 + 12.0, t0 + 12.6, 48.0, 11.0, 500.0, 2.5, 90.0, 4, 0.8, 12))
    msg = " ".join(r.getMessage() for r in caplog.records)
    assert "GNSS epoch at t 12.0 s arrived 0.600 s after it" in msg and "1783670" not in msg


def test_a_message_from_a_second_source_is_counted_not_mixed_in(caplog) -> None:
    """GBSD from a second ECU (0x2C) reporting 0 m/s, interleaved with the radar's (0x1D): both reached the
    estimator as one signal, and a replay of such a capture had no valid step."""
    import logging

    steps = StepAssembler(groups=MACHINE_GROUPS)
    d = FrameDispatcher(CODEC, steps, FixBuffer(GnssGate()))
    caplog.set_level(logging.WARNING, logger="tractionecu.service.dispatch")
    frames = []
    for k in range(10):
        for sa, v in ((0x1D, 2.5), (0x2C, 0.0)):
            cid, data = CODEC.encode("GBSD", {"GroundBasedMachineSpeed": v, "GroundBasedMachineDirection": 1},
                                     sa=sa)
            frames.append(can.Message(arbitration_id=cid, data=data))
    for k, m in enumerate(through_virtual_bus(frames)):
        d.on_frame(1.0 + 0.05 * k, m)
    _, meas = steps.take(2.0)
    assert meas["vr"] == pytest.approx(2.5)
    assert d.stats["other_source_frames"] == 10 and d.stats["rx_GBSD"] == 10
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "GBSD is also sent by source 0x2C: only the frames of 0x1D" in warned[0]
