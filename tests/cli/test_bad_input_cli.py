"""Damaged recordings through the command line: a clear error or a counted skip that the user is told about.

``replay`` over a capture with a garbage line, a line cut short and lines with a NaN or infinite time stamp
runs, and prints how many lines it skipped and where (before, only ``inspect`` said so; ``replay`` wrote
its estimates without a word about the lines it had left out).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tractionecu.cli.main import main


def _damaged(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    for name in ("truth.csv", "truth.toml"):
        (dst / name).unlink(missing_ok=True)
    lines = (dst / "can.log").read_text().splitlines(keepends=True)
    assert len(lines) > 400
    lines.insert(300, "this line is no candump line \x01 ###\n")          # line 303 once the two below are in
    lines.insert(200, "(nan) can0 18FF1080#0102030405060708\n")         # line 202
    lines.insert(100, "(inf) can0 18FF1080#0102030405060708\n")         # line 101
    last = lines[-1].rstrip("\n")
    lines[-1] = last[: len(last) - 5]                                     # cut inside the data field
    (dst / "can.log").write_text("".join(lines))
    return dst


def test_replay_reports_the_lines_it_skipped(short_recording, tmp_path, capsys):
    rec = _damaged(short_recording, tmp_path / "rec")
    n_lines = len((rec / "can.log").read_text().splitlines())
    out = tmp_path / "run"
    assert main(["replay", "--no-map", "--out", str(out), str(rec)]) == 0
    text = capsys.readouterr().out
    assert "skipped bad_timestamp: 2 (can.log line 101, 202)" in text
    assert "skipped garbage: 1 (can.log line 303)" in text
    assert f"skipped truncated: 1 (can.log line {n_lines})" in text
    rows = (out / "estimates.csv").read_text().splitlines()
    assert len(rows) > 100                                      # the rest of the recording was estimated


def test_replay_and_diagnosis_say_what_they_left_out(short_recording, tmp_path, capsys):
    """Frames of a known message one byte short were counted by ``inspect`` only: replay printed nothing
    about them, and diagnosis reported neither those nor the lines the reader skipped.  Without a
    vehicle.toml replay ran the default tractor without a word."""
    from tractionecu.diagnose.data import load

    rec = _damaged(short_recording, tmp_path / "rec")
    lines = (rec / "can.log").read_text().splitlines(keepends=True)
    wheel = [i for i, ln in enumerate(lines) if " 0CFF1080#" in ln]        # TECU_WheelSpeeds (PGN 65296)
    for i in wheel[::10]:                                                  # every 10th frame one byte short
        lines[i] = lines[i].rstrip("\n")[:-2] + "\n"
    (rec / "can.log").write_text("".join(lines))
    (rec / "vehicle.toml").unlink()
    out = tmp_path / "run"
    assert main(["replay", "--no-map", "--out", str(out), str(rec)]) == 0
    text = capsys.readouterr().out
    assert "no vehicle.toml beside the recording: the default machine" in text
    n_short = len(wheel[::10])
    assert f"skipped frames of a known message with the wrong length: TECU_WheelSpeeds {n_short}" in text
    notes = load(rec).notes
    assert any(f"wrong length: TECU_WheelSpeeds {n_short}" in n for n in notes), notes
    assert any(n.startswith("can.log: skipped ") and "garbage: 1 (can.log line 303)" in n for n in notes), notes


def test_replay_of_a_clean_recording_reports_no_skips(short_recording, tmp_path, capsys):
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(short_recording)]) == 0
    assert "skipped" not in capsys.readouterr().out


def test_replay_says_which_loop_ran_and_the_step_path_writes_the_same_estimates(short_recording, tmp_path, capsys):
    """``tractionecu replay`` runs the compiled loop; ``--step-path`` the daemon's Estimator.step: the same
    estimates.csv, byte for byte, and the summary's first line names the loop."""
    assert main(["replay", "--no-map", "--out", str(tmp_path / "fast"), str(short_recording)]) == 0
    assert "; loop: compiled)" in capsys.readouterr().out
    assert main(["replay", "--no-map", "--step-path", "--out", str(tmp_path / "step"), str(short_recording)]) == 0
    assert "; loop: python: compiled=False)" in capsys.readouterr().out
    assert ((tmp_path / "fast" / "estimates.csv").read_bytes() == (tmp_path / "step" / "estimates.csv").read_bytes())


def test_a_replay_into_an_earlier_output_leaves_no_product_of_the_earlier_one(short_recording, tmp_path, capsys):
    """An output directory reused for a recording without GNSS (or with --no-map) kept the earlier
    recording's map, scorecard.json and map_scorecard.json beside the new estimates.csv, and replay said
    'map: 0 of 0 GNSS epochs mapped -> RUN/map': ``map export RUN`` then exported the other recording's map."""
    out = tmp_path / "run"
    assert main(["replay", "--out", str(out), str(short_recording)]) == 0
    assert (out / "map" / "manifest.json").is_file() and (out / "scorecard.json").is_file()
    capsys.readouterr()

    rec = tmp_path / "no_gnss"
    shutil.copytree(short_recording, rec)
    for name in ("gps.nmea", "truth.csv", "truth.toml"):
        (rec / name).unlink()
    assert main(["replay", "--out", str(out), str(rec)]) == 0
    text = capsys.readouterr().out
    assert "map: none written: the recording has no GNSS epoch with a position" in text
    assert "what an earlier replay had written there and this one did not: map, scorecard.json, " \
           "map_scorecard.json" in text
    assert sorted(p.name for p in out.iterdir()) == ["config.toml", "estimates.csv"]
    assert main(["map", "export", str(out), "--format", "geojson"]) == 1     # no map: an error, not the old one


@pytest.mark.parametrize("no_map", [False, True])
def test_a_replay_never_deletes_a_map_folder_it_did_not_write(no_map, short_recording, tmp_path, capsys):
    """An owner's own ``map/`` folder in the output directory (field boundaries: no map manifest) was deleted
    by ``replay --out`` ("removed ... what an earlier replay had written there"), with --no-map by the stale
    products' clean-up and without it by the map writer."""
    out = tmp_path / "run"
    (out / "map").mkdir(parents=True)
    (out / "map" / "boundary.kml").write_text("<kml/>")
    code = main(["replay", "--out", str(out), *(["--no-map"] if no_map else []), str(short_recording)])
    captured = capsys.readouterr()
    assert (out / "map" / "boundary.kml").read_text() == "<kml/>"
    if no_map:
        assert code == 0 and "removed" not in captured.out
    else:
        assert code == 1
        assert "is not a map a replay wrote" in captured.err and "Traceback" not in captured.err
        assert not (out / "estimates.csv").exists()           # refused before the run, nothing half-written


def test_a_gnss_log_without_gga_is_mapped_and_what_is_not_mapped_is_said(short_recording, tmp_path, capsys):
    """RMC and VTG only (no GGA, so no HDOP): the gate let the epochs through, the map refused every one of
    them on the missing HDOP, and replay said only 'map: 0 of 120 GNSS epochs mapped'."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    nmea = (rec / "gps.nmea").read_text().splitlines(keepends=True)
    (rec / "gps.nmea").write_text("".join(ln for ln in nmea if "GGA," not in ln))
    assert main(["replay", "--out", str(tmp_path / "run"), str(rec)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("map: "))
    mapped, epochs = (int(x) for x in line.split()[1:4:2])
    assert epochs > 100 and mapped > 0.8 * epochs, line
    if mapped < epochs:
        assert "(not mapped: " in line and "HDOP" not in line, line


def test_a_replay_that_fails_keeps_what_was_written(short_recording, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["replay", "--out", str(out), str(short_recording)]) == 0
    before = sorted(p.name for p in out.iterdir())
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "can.log").write_text("")
    assert main(["replay", "--out", str(out), str(bad)]) == 1
    assert "empty file" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == before


@pytest.mark.parametrize("arg", [["--duration", "0"], ["--duration", "-5"], ["--duration", "nan"],
                                 ["--duration", "inf"], ["--seed", "-1"]])
def test_simulate_refuses_a_duration_or_seed_it_cannot_run(arg, tmp_path, capsys):
    """A negative, NaN or infinite --duration and a negative --seed ended in numpy tracebacks; 0 s wrote a
    recording of 5 CAN frames and no GNSS line."""
    out = tmp_path / "rec"
    assert main(["simulate", *arg, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert f"tractionecu simulate: error: {arg[0]}:" in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("arg", [["--duration", "5"], ["--speed", "4"], ["--scenario", "s-curves-30m"],
                                 ["--seed", "3"]])
def test_run_refuses_simulation_options_without_simulate(arg, tmp_path, capsys):
    """``tractionecu run --duration 5`` (no ``--simulate``) started the daemon on the configured hardware and ran
    until it was stopped: the simulation's options were ignored without a word."""
    assert main(["run", *arg, "--state-dir", str(tmp_path / "state")]) == 1
    err = capsys.readouterr().err
    assert f"tractionecu run: error: {arg[0]}: simulation options, given without --simulate" in err
    assert "Traceback" not in err
    assert not (tmp_path / "state").exists()


def test_simulate_says_a_mechanical_scenario_on_the_paper_truth_drives_the_hubs(tmp_path, capsys):
    out = tmp_path / "rec"
    assert main(["simulate", "--scenario", "mechanical-three-soils", "--truth", "paper", "--duration", "1",
                 "--out", str(out)]) == 0
    assert "(hub drive: the paper truth model has no engine" in capsys.readouterr().out
    assert 'kind = "hub"' in (out / "vehicle.toml").read_text()


def test_simulate_refuses_an_effect_on_the_physical_truth(tmp_path, capsys):
    """``simulate --scenario physical-three-soils --effect grade`` ended in a ValueError traceback from the
    physical truth model."""
    out = tmp_path / "rec"
    assert main(["simulate", "--scenario", "physical-three-soils", "--effect", "grade", "--duration", "1",
                 "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "tractionecu simulate: error: --effect grade: effects belong to the paper truth model" in err
    assert "Traceback" not in err and not out.exists()


def test_simulate_refuses_an_effect_given_twice(tmp_path, capsys):
    """``--effect grade=2 --effect grade=0.5`` simulated grade 0.5 alone, without a word."""
    out = tmp_path / "rec"
    assert main(["simulate", "--scenario", "paper-straight", "--effect", "grade=2", "--effect", "grade=0.5",
                 "--duration", "1", "--out", str(out)]) == 1
    assert "--effect grade: given more than once" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("rate", ["0", "nan", "inf", "1e9", "0.5"])
def test_replay_refuses_a_step_rate_outside_the_services_range(rate, short_recording, tmp_path, capsys):
    """``--rate 1e9`` ended in a traceback after asking numpy for 149 GiB; inf passed the > 0 test too."""
    assert main(["replay", "--no-map", "--rate", rate, "--out", str(tmp_path / "run"), str(short_recording)]) == 1
    assert "tractionecu replay: error: --rate: an estimator step rate in [1, 1000] Hz" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def _nmea_checksum(body: str) -> str:
    cs = 0
    for c in body:
        cs ^= ord(c)
    return f"${body}*{cs:02X}"


def test_replay_says_when_the_gate_refused_every_gnss_epoch(short_recording, tmp_path, capsys):
    """A receiver without a fix (RMC status V throughout) gave a replay that mapped nothing and ran without
    GNSS speed, and printed only 'map: 0 of N GNSS epochs mapped'."""
    rec = tmp_path / "no_fix"
    shutil.copytree(short_recording, rec)
    lines = []
    for ln in (rec / "gps.nmea").read_text().splitlines():
        f = ln[1:ln.index("*")].split(",")
        if f[0].endswith("RMC"):
            f[2] = "V"
        lines.append(_nmea_checksum(",".join(f)))
    (rec / "gps.nmea").write_text("\n".join(lines) + "\n")
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 0
    out = capsys.readouterr().out
    n = sum(1 for ln in lines if "RMC" in ln)
    assert f"GNSS: {n} of {n} epochs refused by the gate (invalid {n}); no GNSS speed or position reached" in out


def test_replay_reports_the_clock_offset_it_applied(short_recording, tmp_path, capsys):
    """CAN times an hour off the GNSS epochs were moved by the offset found, silently in replay (only
    ``inspect`` said so)."""
    rec = tmp_path / "late_clock"
    shutil.copytree(short_recording, rec)
    out_lines = []
    for ln in (rec / "can.log").read_text().splitlines():
        t, rest = ln[1:].split(")", 1)
        out_lines.append(f"({float(t) + 3600.0:.6f}){rest}")
    (rec / "can.log").write_text("\n".join(out_lines) + "\n")
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 0
    text = capsys.readouterr().out
    assert "clock: the CAN frames" in text and "CAN clock offset -3600.0" in text and text.count("applied") == 1


@pytest.mark.parametrize("arg,why", [(["--seed", "-1"], "--seed: a non-negative integer, got -1"),
                                     (["--duration", "inf"], "--duration: must be > 0 and finite, got inf"),
                                     (["--scenario", "bogus"], "scenario 'bogus': unknown (known: ")])
def test_run_simulate_refuses_what_it_cannot_simulate(arg, why, tmp_path, capsys):
    """``run --simulate --seed -1`` ended in a numpy traceback after announcing the simulation; an unknown
    scenario was announced before it was refused."""
    assert main(["run", "--simulate", "--no-web", "--quiet", "--state-dir", str(tmp_path / "st"), *arg]) == 1
    cap = capsys.readouterr()
    assert f"tractionecu run: error: {why}" in cap.err and "simulating" not in cap.out


def test_an_output_path_that_is_a_file_is_an_error_not_a_traceback(short_recording, tmp_path, capsys):
    """``replay --out FILE`` (and simulate, diagnose, fleet) ended in a FileExistsError traceback."""
    f = tmp_path / "notes.txt"
    f.write_text("mine\n")
    assert main(["replay", "--no-map", "--out", str(f), str(short_recording)]) == 1
    assert f"tractionecu replay: error: {f}: File exists" in capsys.readouterr().err
    assert main(["simulate", "--duration", "1", "--out", str(f)]) == 1
    assert f"tractionecu simulate: error: {f}: File exists" in capsys.readouterr().err
    assert f.read_text() == "mine\n"


def test_simulate_does_not_overwrite_a_recording_it_did_not_make(short_recording, tmp_path, capsys):
    rec = tmp_path / "field_day"
    rec.mkdir()
    shutil.copy(short_recording / "can.log", rec / "can.log")             # a real capture: no truth.toml
    before = (rec / "can.log").read_bytes()
    assert main(["simulate", "--duration", "1", "--out", str(rec)]) == 1
    assert "holds a recording that was not simulated" in capsys.readouterr().err
    assert (rec / "can.log").read_bytes() == before and sorted(p.name for p in rec.iterdir()) == ["can.log"]
    sim = tmp_path / "sim"
    assert main(["simulate", "--duration", "1", "--out", str(sim)]) == 0              # a simulated one may be
    assert main(["simulate", "--duration", "1", "--seed", "2", "--out", str(sim)]) == 0   # simulated again


def test_simulate_again_leaves_no_export_of_the_earlier_run(tmp_path, capsys):
    """A paper run simulated into the directory of a mechanical one kept the mechanical run's export_1hz.csv
    beside the new can.log and truth (diagnose of it diagnosed the other run); a logger's own export_1hz.csv
    without truth.toml was overwritten."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--scenario", "mechanical-three-soils", "--duration", "2", "--out", str(sim)]) == 0
    assert (sim / "export_1hz.csv").is_file()
    assert main(["simulate", "--duration", "2", "--out", str(sim)]) == 0
    assert sorted(p.name for p in sim.iterdir()) == ["can.log", "gps.nmea", "truth.csv", "truth.toml", "vehicle.toml"]
    own = tmp_path / "logger"
    own.mkdir()
    (own / "export_1hz.csv").write_text("Time [s]\n1\n")
    assert main(["simulate", "--scenario", "mechanical-three-soils", "--duration", "2", "--out", str(own)]) == 1
    assert "holds a recording that was not simulated" in capsys.readouterr().err
    assert (own / "export_1hz.csv").read_text() == "Time [s]\n1\n" and len(list(own.iterdir())) == 1


def test_a_vehicle_file_that_is_not_toml_is_named_once(short_recording, tmp_path, capsys):
    """The error read 'rec/vehicle.toml: rec/vehicle.toml: not valid TOML: ...'."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    with open(rec / "vehicle.toml", "a") as fh:
        fh.write("mass_kg = = 3\n")
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 1
    err = capsys.readouterr().err
    assert f"tractionecu replay: error: {rec / 'vehicle.toml'}: not valid TOML: " in err
    assert err.count("vehicle.toml") == 1


def test_diagnose_reads_a_can_capture_in_csv_by_its_content(short_recording, tmp_path, capsys):
    """A python-can CSV capture was taken for a decoded export by its suffix: "line 1: no time column
    'timestamps' in header", while inspect and replay read it (formats are judged by content)."""
    import can

    d = tmp_path / "rec"
    d.mkdir()
    shutil.copy(short_recording / "gps.nmea", d / "gps.nmea")
    shutil.copy(short_recording / "vehicle.toml", d / "vehicle.toml")
    with can.CSVWriter(str(d / "capture.csv")) as w:
        for msg in can.LogReader(str(short_recording / "can.log")):
            w.on_message_received(msg)
    code = main(["diagnose", str(d / "capture.csv"), "--out", str(tmp_path / "diag"), "--no-estimator"])
    captured = capsys.readouterr()
    assert "no time column" not in captured.err and "Traceback" not in captured.err
    assert code in (0, 4) and (tmp_path / "diag" / "report.json").is_file()


@pytest.mark.parametrize("toml, said", [
    ('[signals]\nWheelSpeed_FL = "Nope.Nothing"\n', "dbc = [\"FILE\"] in the service's [can] table"),
    ('[can]\ndbc = ["nonexist.dbc"]\n', "can.dbc: file not found: nonexist.dbc"),
])
def test_run_simulate_checks_the_owner_dbc_before_it_simulates(toml, said, tmp_path, capsys):
    """A bad [signals] entry or a missing can.dbc file was reported only after the whole scenario had been
    simulated, told the user of an option run does not have (--dbc), named neither key nor table for the
    missing file, and left the virtual bus open ("VirtualBus was not properly shut down")."""
    cfg = tmp_path / "svc.toml"
    cfg.write_text(toml)
    code = main(["run", "--simulate", "--duration", "5", "--config", str(cfg), "--state-dir", str(tmp_path / "st")])
    err = capsys.readouterr().err
    assert code != 0 and said in err
    assert not (tmp_path / "st" / "simulation").exists()          # refused before simulating


def test_run_simulate_says_which_hardware_options_it_does_not_use(tmp_path, capsys):
    """--gps-port, --interface, --channel and estimation.vehicle were dropped by --simulate without a word."""
    code = main(["run", "--simulate", "--duration", "3", "--speed", "8", "--gps-port", "/dev/ttyS9",
                 "--interface", "socketcan", "--state-dir", str(tmp_path / "st"), "--no-web"])
    err = capsys.readouterr().err
    assert code == 0 and "--interface, --gps-port: not used with --simulate" in err


def test_map_export_says_what_is_missing(short_recording, tmp_path, capsys):
    """``map export`` of a directory that does not exist, or of a replay run with --no-map, said only
    "DIR/manifest.json: no map manifest"."""
    assert main(["map", "export", str(tmp_path / "nonexist"), "--format", "geojson"]) == 1
    assert "nonexist: no such directory" in capsys.readouterr().err
    out = tmp_path / "run"
    assert main(["replay", "--no-map", "--out", str(out), str(short_recording)]) == 0
    capsys.readouterr()
    assert main(["map", "export", str(out), "--format", "geojson"]) == 1
    assert "a replay's output without a map (replayed with --no-map" in capsys.readouterr().err


def test_simulate_counts_the_frames_it_writes(tmp_path, capsys):
    """A mechanical recording reported 18 more CAN frames than can.log holds: each EC1 message was counted
    on top of the transport-protocol frames that carry it."""
    out = tmp_path / "m"
    assert main(["simulate", "--scenario", "mechanical-three-soils", "--duration", "12", "--out", str(out)]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    n = int(line.split(" CAN frames")[0].split()[-1])
    assert n == len((out / "can.log").read_text().splitlines())


def test_a_capture_out_of_time_order_is_named_with_how_to_sort_it(short_recording, tmp_path, capsys):
    """Frames stamped on arrival with jitter, or merged from two interfaces, come out of time order; every
    frame earlier than one before it is left out (about half here), which was counted but not explained."""
    import subprocess

    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    lines = (rec / "can.log").read_text().splitlines(keepends=True)
    for i in range(0, len(lines) - 1, 2):                      # swap neighbours: each second frame goes back
        lines[i], lines[i + 1] = lines[i + 1], lines[i]
    (rec / "can.log").write_text("".join(lines))
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 0
    text = capsys.readouterr().out
    hint = [ln for ln in text.splitlines() if ln.startswith("can.log: ")]
    assert len(hint) == 1 and "are stamped earlier than a line before them and were left out" in hint[0]
    # the command it names puts the capture back in order: nothing is left out then
    cmd = hint[0].split("(candump -L: ")[1].rstrip(")").replace(" can.log ", f" {rec / 'can.log'} ")
    sorted_log = rec / "sorted.log"
    subprocess.run(cmd.replace("> sorted.log", f"> {sorted_log}"), shell=True, check=True)
    sorted_log.replace(rec / "can.log")
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run2"), str(rec)]) == 0
    assert "time_backwards" not in capsys.readouterr().out


def test_plots_of_a_recording_without_truth_and_without_a_map(short_recording, tmp_path, capsys):
    """replay --plot --no-map on a recording without truth.csv ended in an IndexError: the streamed replay kept
    only the map's steps (none without a map) and the figures were drawn from an empty array."""
    pytest.importorskip("matplotlib")
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    for name in ("truth.csv", "truth.toml"):
        (rec / name).unlink(missing_ok=True)
    out = tmp_path / "run"
    assert main(["replay", "--plot", "--no-map", "--out", str(out), str(rec)]) == 0
    text = capsys.readouterr().out
    for name in ("fig6_mu_rho.png", "fig_efficiency.png", "report.html"):
        assert (out / name).stat().st_size > 1000 and f"plot: {out / name}" in text


def test_an_export_of_the_replaced_map_goes_with_it(short_recording, tmp_path, capsys):
    """``map export RUN`` writes RUN/export/; a later replay into RUN replaced the map and kept the old map's
    GeoJSON and GeoTIFF beside it (the GeoTIFF's origin tag still the old map's)."""
    out = tmp_path / "run"
    assert main(["replay", "--out", str(out), str(short_recording)]) == 0
    assert main(["map", "export", str(out), "--format", "geojson"]) == 0
    assert (out / "export" / "map.geojson").is_file()
    (out / "export" / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main(["replay", "--out", str(out), "--no-map", str(short_recording)]) == 0
    assert "export/map.geojson" in capsys.readouterr().out
    assert not (out / "export" / "map.geojson").exists()
    assert (out / "export" / "notes.txt").read_text() == "mine"       # only what map export writes goes


def test_an_interrupted_replay_leaves_the_earlier_estimates_whole(short_recording, tmp_path, monkeypatch):
    """Ctrl-C 2.6 s into a replay into an earlier run's folder cut its estimates.csv from 9003 lines to 1,
    beside the earlier map and scorecard."""
    from tractionecu.pipeline import replay as rp

    out = tmp_path / "run"
    assert main(["replay", "--out", str(out), str(short_recording)]) == 0
    before = (out / "estimates.csv").read_bytes()

    def interrupted(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(rp._Run, "close", interrupted)
    assert main(["replay", "--out", str(out), str(short_recording)]) == 130
    assert (out / "estimates.csv").read_bytes() == before
    assert not (out / "estimates.csv.partial").exists()


def test_a_can_clock_stepped_while_logging_is_said_by_replay(short_recording, tmp_path, capsys):
    """A capture whose first half was stamped by an unset logger clock (1970) and whose second half by GNSS
    time replayed with exit 0 and no word, "1783670390.0 s simulated … (2030976327x real time)": only
    inspect warned of the jump."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    lines = (rec / "can.log").read_text().splitlines()
    t0 = float(lines[0][1:lines[0].index(")")])
    cut = t0 + 6.0
    out_lines = []
    for ln in lines:
        t = float(ln[1:ln.index(")")])
        out_lines.append(f"({t - t0 + 100.0:.6f}){ln[ln.index(')') + 1:]}" if t < cut else ln)
    (rec / "can.log").write_text("\n".join(out_lines) + "\n")
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 0
    text = capsys.readouterr().out
    assert "WARNING: 1 time jump(s) between consecutive CAN frames" in text
    head = next(ln for ln in text.splitlines() if ln.startswith("replay: "))
    simulated = float(head.split()[3])
    assert simulated <= 12.5, head


def test_an_empty_gnss_log_is_a_recording_without_gnss(short_recording, tmp_path, capsys):
    """A zero-byte gps.nmea refused the whole recording ("gps.nmea: empty file", exit 1), while the same
    recording without the file, or with two blank lines in it, was replayed."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    (rec / "gps.nmea").write_bytes(b"")
    assert main(["inspect", str(rec)]) == 0
    assert "gps.nmea: 0 lines" in capsys.readouterr().out
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 0
    assert len((tmp_path / "run" / "estimates.csv").read_text().splitlines()) > 1000


def test_a_curve_never_identified_is_said(short_recording, tmp_path, capsys):
    """With a 1 Hz GNSS receiver every step held a = NaN (slip not supported) and the map had no a layer; the
    replay exited 0 saying only how many epochs it mapped."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    lines = (rec / "gps.nmea").read_text().splitlines(keepends=True)
    keep = [ln for ln in lines if not (ln.startswith("$") and "," in ln and ln.split(",")[1][:6].isdigit()
                                       and ln.split(",")[1][7:9] not in ("", "00"))]
    (rec / "gps.nmea").write_text("".join(keep))
    assert main(["replay", "--out", str(tmp_path / "run"), str(rec)]) == 0
    out = capsys.readouterr().out
    assert "curve: a was never identified: the slip was not supported on" in out and "GNSS epochs at 1.0 Hz" in out
    assert main(["replay", "--out", str(tmp_path / "run2"), str(short_recording)]) == 0
    assert "a was never identified" not in capsys.readouterr().out


def test_a_logger_restart_is_named_with_where_to_split(short_recording, tmp_path, capsys):
    """A logger that restarted mid-capture (its clock from 0 again): half the frames dropped as stamped earlier,
    and the hint to sort the capture interleaved the two runs, after which replay refused it."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    lines = (rec / "can.log").read_text().splitlines()
    half = len(lines) // 2
    t0 = float(lines[0][1:lines[0].index(")")])
    t1 = float(lines[half][1:lines[half].index(")")])
    second = [f"({float(ln[1:ln.index(')')]) - t1 + t0:.6f}){ln[ln.index(')') + 1:]}" for ln in lines[half:]]
    (rec / "can.log").write_text("\n".join(lines[:half] + second) + "\n")
    assert main(["replay", "--no-map", "--out", str(tmp_path / "run"), str(rec)]) == 0
    out = capsys.readouterr().out
    assert f"can.log: its clock restarted at line {half + 2}" in out or f"its clock restarted at line {half + 1}" in out
    assert "split the capture at line" in out and "sort -s" not in out


def test_ctrl_c_stops_run_simulate_while_it_simulates(tmp_path):
    """Ctrl-C while ``run --simulate`` simulated (a first run also compiles its kernels, about 45 s) was
    held until the whole simulation was done, because it ran in the event loop's executor thread: the
    command then exited without a word.  It now simulates in the main thread and stops at once."""
    import os
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "tractionecu", "run", "--simulate", "--scenario", "paper-three-soils",
         "--no-web", "--quiet", "--state-dir", str(tmp_path / "st")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")},     # a first run's cold cache
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))           # as from a terminal
    try:
        assert "simulating paper-three-soils" in proc.stdout.readline()
        proc.send_signal(signal.SIGINT)
        # the simulation and its compilation alone take minutes; a stop at once takes well under a second
        rc = proc.wait(timeout=60)
    finally:
        proc.kill()
        rest = proc.communicate()[0]
    assert rc == 130, rest
    assert "playing on virtual CAN" not in rest
    assert not (tmp_path / "st" / "simulation" / "can.log").exists()      # stopped before the end, not after it


@pytest.mark.parametrize("arg", [["--time-offset", "nan"], ["--time-offset", "inf"], ["--reference-torque", "inf"],
                                 ["--reference-torque", "1e300"], ["--reference-torque", "-1"]])
def test_diagnose_refuses_a_time_offset_or_reference_torque_that_is_no_number(arg, tmp_path, capsys):
    """``--time-offset nan`` on a 1 Hz export ended in "no signal with more than two samples", and
    ``--reference-torque inf`` in the verdict untestable, "missing signals: engine_torque" (exit 4): the value
    given was reported as the export's data."""
    export = Path(__file__).resolve().parents[1] / "data" / "csv" / "css_engine_gnss_1hz.csv"
    args = ["--reference-torque", "1000"] if arg[0] == "--time-offset" else []
    out = tmp_path / "diag"
    assert main(["diagnose", str(export), "--csv-mapping", "auto", "--out", str(out), *args, *arg]) == 1
    err = capsys.readouterr().err
    assert f"tractionecu diagnose: error: {arg[0]}: must be" in err and "Traceback" not in err
    assert not out.exists()


def test_an_interrupted_diagnosis_leaves_the_earlier_report_with_its_figures(short_recording, tmp_path, monkeypatch):
    """Ctrl-C while the figures were drawn, in a folder an earlier diagnosis had written: report.json and
    report.md were the new ones already, beside the earlier diagnosis's figures."""
    from tractionecu.diagnose import report

    out = tmp_path / "diag"
    assert main(["diagnose", "--no-estimator", "--out", str(out), str(short_recording)]) in (0, 4)
    (out / "report.md").write_text("the earlier report\n")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert set(before) == {"report.json", "report.md", "residual_before_after.png", "residual_map.png", "ranking.png"}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "plot_ranking", interrupted)
    assert main(["diagnose", "--no-estimator", "--out", str(out), str(short_recording)]) == 130
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize("arg", [["--csv-mapping", "auto"], ["--csv-timezone", "+02:00"]])
def test_diagnose_says_a_csv_option_does_not_fit_a_recording_directory(arg, short_recording, tmp_path, capsys):
    """``diagnose REC --csv-mapping auto`` on a recording directory: "REC: cannot read: Is a directory"."""
    out = tmp_path / "diag"
    assert main(["diagnose", str(short_recording), "--out", str(out), *arg]) == 1
    err = capsys.readouterr().err
    assert "for a decoded CSV export" in err and "is a recording directory" in err and "Is a directory" not in err
    assert not out.exists()


def test_diagnose_help_gives_the_verdicts_and_exit_statuses(capsys):
    """``diagnose --help`` named neither the verdicts nor that untestable exits 4."""
    with pytest.raises(SystemExit) as ex:
        main(["diagnose", "--help"])
    assert ex.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "effect, ambiguous, none, unexplained" in out and "untestable" in out
    assert "exit status: 0 with a verdict, 4 with the verdict untestable" in out


def test_ctrl_c_while_the_commands_are_imported_exits_130_without_a_traceback(monkeypatch):
    """The subcommands' imports take seconds on a cold start; Ctrl-C then printed an import's traceback."""
    from tractionecu.cli import main as cli_main

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_main, "build_parser", interrupted)
    assert cli_main.main(["inspect", "x"]) == 130
