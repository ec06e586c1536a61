"""Input dispatch: each received CAN frame and GNSS fix to where it belongs, or counted.

:meth:`FrameDispatcher.on_frame` (the CAN link's frame handler) sorts a frame:

==============================  ==============================================
frame                           goes to / counted as
==============================  ==============================================
error, remote, CAN FD          ``error_frames``, ``remote_frames``,
                                ``canfd_frames``
11-bit                          an owner's DBC message on that identifier:
                                decoded as below; else ``standard_id_frames``
Address Claimed, Request        the network (:meth:`.network.Network.on_nm_frame`)
a PGN not in the DBC            ``unknown_pgn_frames`` and per PGN in
                                :attr:`FrameDispatcher.unknown_pgns` (at most
                                :data:`MAX_TRACKED_UNKNOWN_PGNS`, then
                                ``unknown_pgn_untracked``)
an estimate PGN (another ECU)   ``foreign_estimate_frames``
a DBC frame that fails to       ``bad_frames`` and per message in
decode (wrong DLC ...)          :attr:`FrameDispatcher.bad_frames`; logged once
a DBC frame                     decoded: ``decoded_frames``, ``rx_<message>``;
                                its signals to the step assembler (which phases
                                the grid on the first wheel-speed frame)
TP.CM / TP.DT (J1939-21)        ``tp_frames``; a multi-packet message they
                                complete (EC1, an owner's long message) is
                                decoded like a frame (``tp_messages``)
==============================  ==============================================

The owner's own messages: a ``[signals]`` mapping (resolved against the
codec, :meth:`~tractionecu.bus.dbc.Codec.resolve_mapping`) adds, to the
values of a frame carrying a mapped source signal, the contract name with
the source value times its scale, as the recording reader does.

:meth:`FrameDispatcher.on_fix` (the GNSS reader's sample handler) keeps the
fix in the :class:`~.fixes.FixBuffer` (for the map), counts ``gps_fixes``
and gives its speed over ground to the step assembler; a fix that arrives
after its step was taken is used one step late (counted by the assembler,
logged once).

Bad input never raises here: the daemon keeps running on any bus traffic.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, Callable, Sequence

import can

from ..bus import j1939
from ..bus.dbc import Codec
from ..bus.transport import TRANSPORT_PGNS, Reassembler, message_id
from ..counting import WarnOnce
from ..errors import ConfigError, DecodeError
from ..pipeline.steps import StepAssembler
from .broadcast import output_pgns
from .fixes import FixBuffer
from .gps import GpsSample

log = logging.getLogger(__name__)

NM_PGNS = frozenset({j1939.PGN_ADDRESS_CLAIMED, j1939.PGN_REQUEST})
"""Network-management PGNs: handed to the network."""

MAX_TRACKED_UNKNOWN_PGNS = 256
"""Unknown PGNs counted one by one (:attr:`FrameDispatcher.unknown_pgns`); frames of further ones are
counted together as ``unknown_pgn_untracked``.  A real bus carries a few dozen."""


class FrameDispatcher:
    """Sort received frames and fixes (module doc).

    Parameters
    ----------
    codec:
        The DBC codec.
    steps:
        The step assembler the decoded signals and GNSS speeds go to.
    fixes:
        The fix buffer accepted fixes go to.
    on_network:
        ``on_network(can_id, data)`` for Address Claimed and Request frames
        (None: they are only counted as ``network_management``).
    stats:
        Counter for the frame and fix counts (default: a new one).
    lag_s:
        ``estimation.lag_s`` (named in the warning about late fixes).
    mapping:
        ``[(contract name, source key, scale)]`` of the ``[signals]`` table
        (:meth:`~tractionecu.bus.dbc.Codec.resolve_mapping`); empty: none.
    """

    def __init__(self, codec: Codec, steps: StepAssembler, fixes: FixBuffer, *,
                 on_network: Callable[[int, bytes], None] | None = None,
                 stats: Counter[str] | None = None, lag_s: float = 0.0,
                 mapping: Sequence[tuple[str, str, float]] = ()) -> None:
        self.codec = codec
        self.steps = steps
        self.fixes = fixes
        self.on_network = on_network
        self.stats: Counter[str] = Counter() if stats is None else stats
        self.lag_s = lag_s
        self.unknown_pgns: Counter[int] = Counter()
        self.bad_frames: Counter[str] = Counter()
        self._output_pgns = output_pgns(codec)
        self._warn = WarnOnce(log)
        self.tp = Reassembler()
        self._source: dict[str, int] = {}
        """The source address whose frames give each message's signals (the first seen)."""
        self._mapped: dict[str, list[tuple[str, float]]] = {}
        for target, src, scale in mapping:
            self._mapped.setdefault(src, []).append((target, scale))

    def on_frame(self, t: float, msg: can.Message) -> None:
        """One received frame, stamped ``t`` [service s]."""
        st = self.stats
        if msg.is_error_frame:
            st["error_frames"] += 1
            return
        if msg.is_remote_frame:
            st["remote_frames"] += 1
            return
        if msg.is_fd:
            st["canfd_frames"] += 1
            return
        if not msg.is_extended_id:
            info = self.codec.message_for_std_id(msg.arbitration_id)
            if info is None:
                st["standard_id_frames"] += 1
                return
            self._decoded(t, msg.arbitration_id, bytes(msg.data), info.name, extended=False)
            return
        cid = msg.arbitration_id
        pgn = j1939.pgn_of(cid)
        if pgn in NM_PGNS:
            if self.on_network is None:
                st["network_management"] += 1
            else:
                self.on_network(cid, bytes(msg.data))
            return
        if pgn in TRANSPORT_PGNS:
            st["tp_frames"] += 1
            done = self.tp.feed(cid, bytes(msg.data), t)
            if done is None:
                return
            pgn, sa, payload = done
            info = self.codec.message_for_pgn(pgn)
            if info is None or pgn in self._output_pgns:
                st["tp_unused_messages"] += 1
                return
            st["tp_messages"] += 1
            self._decoded(t, message_id(pgn, sa), payload, info.name)
            return
        info = self.codec.message_for_pgn(pgn)
        if info is None:
            if pgn in self.unknown_pgns or len(self.unknown_pgns) < MAX_TRACKED_UNKNOWN_PGNS:
                self.unknown_pgns[pgn] += 1
            else:                               # hostile traffic must not grow the table to 2^18 keys
                st["unknown_pgn_untracked"] += 1
            st["unknown_pgn_frames"] += 1
            return
        if pgn in self._output_pgns:
            st["foreign_estimate_frames"] += 1
            return
        self._decoded(t, cid, bytes(msg.data), info.name)

    def _decoded(self, t: float, cid: int, data: bytes, message: str, extended: bool = True) -> None:
        """Decode a frame (or a reassembled message) of a DBC message and give its signals to the steps."""
        st = self.stats
        sa = cid & 0xFF if extended else None
        if sa is not None:
            # one source per message, the first decoded, as the recording reader (fastdecode.one_source): one
            # PGN from two ECUs is two measurements, interleaved they are neither
            used = self._source.get(message, sa)
            if sa != used:
                st["other_source_frames"] += 1
                self._warn("source:" + message, "%s is also sent by source 0x%02X: only the frames of 0x%02X, the "
                           "first seen, are used", message, sa, used)
                return
        try:
            name, values = self.codec.decode(cid, data, extended)
        except (DecodeError, KeyError, ValueError) as e:
            self.bad_frames[message] += 1
            st["bad_frames"] += 1
            self._warn("bad:" + message, "skipped frame %s#%s: %s", f"{cid:08X}" if extended else f"{cid:03X}",
                       data.hex().upper(), e)
            return
        if sa is not None:
            self._source.setdefault(message, sa)
        st["decoded_frames"] += 1
        st["rx_" + name] += 1
        if self._mapped:
            for src in [k for k in values if k in self._mapped]:
                for target, scale in self._mapped[src]:
                    values[target] = values[src] * scale
        anchored = self.steps.anchor is not None
        try:
            self.steps.push_signals(t, values)
        except KeyError as e:                   # a per-wheel group mapped from several messages
            st["incomplete_group_frames"] += 1
            self._warn("group:" + name, "%s: signal %s of its per-wheel group is not in this message; map the "
                       "group's signals from one message", name, e)
            return
        if not anchored and self.steps.anchor is not None:
            log.info("estimation grid phased to the first anchor frame: t0 = %.6f", self.steps.anchor)

    def on_fix(self, fix: GpsSample) -> None:
        """One accepted GNSS fix."""
        self.fixes.add(fix)
        self.stats["gps_fixes"] += 1
        if fix.speed_mps is not None:
            late = self.steps.counts["late"]
            self.steps.push_speed(fix.t, fix.speed_mps, fix.course_deg)
            if self.steps.counts["late"] > late:
                t0 = self.steps.anchor if self.steps.anchor is not None else fix.t
                self._warn("late-gps", "GNSS epoch at t %.1f s arrived %.3f s after it (lag %.3f s): it is used one "
                           "step late; raise estimation.lag_s", fix.t - t0, fix.t_arrival - fix.t, self.lag_s)


def codec_for(cfg: Any, codec: Codec | None = None) -> tuple[Codec, list[tuple[str, str, float]]]:
    """The codec of a service config (the built-in DBC and ``can.dbc``) and its resolved ``[signals]``
    mapping (:meth:`~tractionecu.config.ServiceConfig.signal_mapping`).  A given ``codec`` is extended by
    ``can.dbc``.  Raises :class:`~tractionecu.errors.ConfigError` naming ``signals.<name>`` or the DBC file."""
    from ..bus.dbc import default_codec

    files = cfg.dbc_files()
    if files:
        try:
            codec = Codec(codec.path if codec is not None else None,
                          extra=[*(codec.extra_paths if codec is not None else ()), *files])
        except ConfigError as e:           # "dbc: file not found: F" named neither the key nor the table
            raise ConfigError(f"can.{e}" if str(e).startswith("dbc:") else str(e)) from None
    codec = codec or default_codec()
    mapping = cfg.signal_mapping()
    try:
        return codec, codec.resolve_mapping(mapping)
    except ConfigError as e:
        # a key of the vehicle file's [signals] is named with that file: the service config has a [signals] too
        # ("signals.WheelSpeed_FL: no message 'Nope'" named neither)
        veh = cfg.estimation.vehicle
        if veh and any(str(e).startswith(f"signals.{k}:") for k in mapping if k not in cfg.signals):
            raise ConfigError(f"{veh}: {e}") from None
        raise
