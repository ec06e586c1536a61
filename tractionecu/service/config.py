"""Configuration of the in-cab service: frozen dataclasses loaded from TOML.

Every field has a doc line with its unit.  Values are validated when a
dataclass is built; a :class:`~tractionecu.errors.ConfigError` always names
the offending key as ``section.key``.  Example (all keys optional)::

    [can]
    interface = "socketcan"      # any python-can interface name
    channel = "can0"

    [gps]
    port = "/dev/ttyACM0"
    baudrate = 115200

    [estimation]
    vehicle = "/etc/tractionecu/vehicle.toml"

    [sensors]
    gps_speed_sigma = 0.02       # overrides the vehicle file's [sensors]

    [broadcast]
    name = "0xA2000000000001"    # 64-bit J1939 NAME (hex string or integer)
    preferred_address = 144

    [map]
    origin_lat = 47.88
    origin_lon = -110.55

    [advice]
    axle_type = "mfwd"           # slip band 8-12 %

    [web]
    host = "127.0.0.1"           # the in-cab page: http://127.0.0.1:8080/
    port = 8080

    [signals]                    # the owner's messages (can.dbc = ["owner.dbc"]) onto contract names
    WheelSpeed_FL = "DriveCtrl_3.WhlSpdFL"

Sensor figures (:class:`~tractionecu.config.SensorSpec`) resolve key by key:
a key of this file's ``[sensors]`` overrides the same key of the vehicle
file's ``[sensors]`` (``estimation.vehicle``), and a key set in neither takes
its documented default (:meth:`ServiceConfig.resolved_sensors`).

The tables are declared, read and written with the package's config base
(:mod:`tractionecu.config`).  ``systemd/tractionecu.toml`` in the repository
is a commented example.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

from .. import config as base
from ..bus import j1939
from ..config import SensorSpec, given_keys, resolve_sensors, section, setting, table, validate
from ..errors import ConfigError

STATE_DIR_ENV = "STATE_DIRECTORY"
"""Set by systemd from ``StateDirectory=``; the default state directory when present."""

DEFAULT_STATE_DIR = "tractionecu-state"
"""State directory (relative to the working directory) when neither the config nor systemd names one."""

SELF_CONFIGURABLE_RANGE = (128, 247)
"""Addresses a self-configurable control function of industry group 2 may take (ISO 11783-5)."""


def default_name() -> j1939.Name:
    """The service's default NAME: agriculture (industry group 2), self-configurable.

    ``manufacturer_code`` 0 is not an SAE-assigned code: a machine builder sets
    its own code and a unique ``identity_number`` in the config.  With the
    self-configurable bit (63) set, the NAME loses every contention against a
    fixed-address NAME, as a retro-fitted add-on should.
    """
    return j1939.Name(
        identity_number=1,
        manufacturer_code=0,
        ecu_instance=0,
        function_instance=0,
        function=255,
        vehicle_system=0,
        vehicle_system_instance=0,
        industry_group=j1939.INDUSTRY_GROUP_AGRICULTURE,
        arbitrary_address_capable=True,
    )


@dataclass(frozen=True)
class CanConfig:
    """The CAN bus, through python-can."""

    interface: str = setting("socketcan", "python-can interface name (socketcan, virtual, pcan, kvaser, slcan, ...)")
    channel: str = setting("can0", "python-can channel (socketcan: network interface name)")
    timestamps: str = setting("auto", "frame times: 'kernel' (the driver's receive time), 'receipt' (when read), "
                                 "'auto' (kernel for socketcan, else receipt)")
    rx_buffer_bytes: int = setting(2 * 1024 * 1024, "socketcan receive buffer (SO_RCVBUF; the kernel caps it at "
                                                 "net.core.rmem_max) [bytes]", 16384, 256 * 1024 * 1024)
    rx_queue_frames: int = setting(4096, "bound of the receive queue between a reader thread and the event loop [frames]", 16, 1_000_000)
    reopen_min_s: float = setting(0.5, "first wait before reopening a failed interface [s]", 0.01, 60.0)
    reopen_max_s: float = setting(1.0, "longest wait between reopen attempts (doubling backoff) [s]", 0.01, 600.0)
    silence_reopen_s: float = setting(0.0, "reopen the interface after this long without any frame [s]; 0 = never", 0.0, 3600.0)
    kernel_filters: bool = setting(True, "receive only the DBC's PGNs (any source address): SocketCAN drops the rest in "
                                    "the kernel; false = receive everything and count what is skipped")
    dbc: tuple[str, ...] = setting(("",), "the owner's DBC files, decoded by PGN beside the built-in DBC (their "
                                   "signals are named Message.Signal; [signals] maps them onto contract names)")
    options: Mapping[str, Any] = table("extra keyword arguments for can.Bus (e.g. bitrate)")

    def __post_init__(self) -> None:
        validate(self, "can")
        from can.interfaces import VALID_INTERFACES

        if self.interface not in VALID_INTERFACES:
            raise ConfigError(
                f"can.interface: unknown python-can interface {self.interface!r} "
                f"(known: {', '.join(sorted(VALID_INTERFACES))})"
            )
        if not self.channel:
            raise ConfigError("can.channel: must not be empty")
        if self.timestamps not in ("auto", "kernel", "receipt"):
            raise ConfigError(f"can.timestamps: {self.timestamps!r} is not one of auto, kernel, receipt")
        if self.reopen_max_s < self.reopen_min_s:
            raise ConfigError(f"can.reopen_max_s = {self.reopen_max_s} is below can.reopen_min_s = {self.reopen_min_s}")
        for k in ("interface", "channel", "can_filters"):
            if k in self.options:
                raise ConfigError(f"can.options.{k}: set can.{k} instead")

    @property
    def kernel_timestamps(self) -> bool:
        """True if frame times come from the driver (``msg.timestamp``)."""
        return self.timestamps == "kernel" or (self.timestamps == "auto" and self.interface == "socketcan")


@dataclass(frozen=True)
class GpsConfig:
    """The GNSS receiver: NMEA 0183 on a serial port."""

    source: str = setting("serial", "'serial' (NMEA from a serial port) or 'none' (no GNSS: no map, no GPS speed)")
    port: str = setting("/dev/ttyACM0", "serial device of the receiver")
    baudrate: int = setting(115200, "serial speed [bit/s]", 300, 4_000_000)
    min_fix_quality: int = setting(1, "least accurate GGA fix quality accepted, in the order 1 autonomous, 2 DGNSS, "
                                      "5 RTK float, 4 RTK fixed (6-8, dead reckoning, manual and simulated, never)", 1, 5)
    max_hdop: float = setting(5.0, "highest accepted HDOP [-]", 0.1, 99.0)
    latency_s: float = setting(0.0, "receiver output latency subtracted from the arrival time of an epoch [s]", 0.0, 1.0)
    max_line_bytes: int = setting(160, "longer lines are rejected as garbage [bytes] (NMEA allows 82)", 82, 4096)
    reopen_min_s: float = setting(0.5, "first wait before reopening the port [s]", 0.01, 60.0)
    reopen_max_s: float = setting(5.0, "longest wait between reopen attempts [s]", 0.01, 600.0)

    def __post_init__(self) -> None:
        validate(self, "gps")
        if self.source not in ("serial", "none"):
            raise ConfigError(f"gps.source: {self.source!r} is not one of serial, none")
        if self.source == "serial" and not self.port:
            raise ConfigError("gps.port: must not be empty when gps.source = 'serial'")
        if self.reopen_max_s < self.reopen_min_s:
            raise ConfigError(f"gps.reopen_max_s = {self.reopen_max_s} is below gps.reopen_min_s = {self.reopen_min_s}")


@dataclass(frozen=True)
class EstimationConfig:
    """The fixed-rate estimation loop."""

    rate_hz: float = setting(100.0, "estimator step rate [Hz]", 1.0, 1000.0)
    lag_s: float = setting(0.01, "each step runs this long after its grid time, so every frame stamped "
                            "before the grid time has arrived [s]", 0.0, 1.0)
    max_catch_up_s: float = setting(1.0, "when the loop falls further behind than this, it skips ahead [s]", 0.01, 60.0)
    vehicle: str = setting("", "vehicle.toml with the nominal VehicleParams; empty = built-in defaults")
    wheel_speed_timeout_s: float = setting(0.05, "wheel speeds older than this are not used (status 0x01), "
                                 "or older than timeout_periods of their observed period when that is longer [s]", 0.001, 10.0)
    ground_speed_timeout_s: float = setting(0.5, "ground speed older than this is not used (status 0x02), "
                                 "or older than timeout_periods of its observed period when that is longer [s]", 0.001, 10.0)
    torque_timeout_s: float = setting(0.05, "drive torques (engine torque) older than this: predict only (status 0x04), "
                                 "or older than timeout_periods of their observed period when that is longer [s]", 0.001, 10.0)
    axle_load_timeout_s: float = setting(0.1, "front-axle load older than this: predict only (status 0x08), "
                                 "or older than timeout_periods of its observed period when that is longer [s]", 0.001, 10.0)
    draft_timeout_s: float = setting(0.1, "draft force older than this: predict only (status 0x10), "
                                 "or older than timeout_periods of its observed period when that is longer [s]", 0.001, 10.0)

    def __post_init__(self) -> None:
        validate(self, "estimation")


@dataclass(frozen=True)
class BroadcastConfig:
    """Broadcast of the estimates and the J1939 address claim."""

    rate_hz: float = setting(10.0, "broadcast rate of the three estimate PGNs [Hz]; must divide estimation.rate_hz", 0.1, 100.0)
    name: str = setting("", "64-bit J1939 NAME as hex string ('0x...') or integer; empty = the built-in default")
    preferred_address: int = setting(j1939.DEFAULT_SERVICE_ADDRESS, "source address claimed first", 0, 253)
    address_min: int = setting(SELF_CONFIGURABLE_RANGE[0], "lowest address a self-configurable NAME may move to", 0, 253)
    address_max: int = setting(SELF_CONFIGURABLE_RANGE[1], "highest address a self-configurable NAME may move to", 0, 253)
    priority: int = setting(6, "J1939 priority of the estimate frames (0 highest, 7 lowest)", 0, 7)
    enabled: bool = setting(True, "send estimates on the bus (false: listen only, no address claim)")
    requests_per_tick: int = setting(8, "J1939 Requests served after each estimation step; more wait, and beyond "
                                     "64 waiting they are shed (counted) [requests/step]", 1, 1000)
    request_answer_interval_s: float = setting(0.1, "the same PGN is answered to the same requester at most once "
                                               "per interval; keep it under the 0.2 s J1939 response time [s]",
                                               0.0, 0.2)

    def __post_init__(self) -> None:
        if isinstance(self.name, int) and not isinstance(self.name, bool):
            object.__setattr__(self, "name", hex(self.name))
        validate(self, "broadcast")
        self.name_value()  # validates
        if self.address_max < self.address_min:
            raise ConfigError(f"broadcast.address_max = {self.address_max} is below broadcast.address_min = {self.address_min}")

    def name_value(self) -> j1939.Name:
        """The NAME as :class:`~tractionecu.bus.j1939.Name`."""
        if not self.name:
            return default_name()
        try:
            v = int(self.name.replace("_", ""), 0)
        except ValueError:
            raise ConfigError(f"broadcast.name: {self.name!r} is not an integer or '0x...' hex string") from None
        try:
            n = j1939.Name.from_int(v)
        except ValueError as e:
            raise ConfigError(f"broadcast.name: {e}") from None
        if n.industry_group != j1939.INDUSTRY_GROUP_AGRICULTURE:
            raise ConfigError(
                f"broadcast.name: industry group {n.industry_group}, expected "
                f"{j1939.INDUSTRY_GROUP_AGRICULTURE} (agricultural and forestry equipment)"
            )
        return n


@dataclass(frozen=True)
class MapConfig:
    """The map writer."""

    enabled: bool = setting(True, "accumulate the estimates into map tiles")
    directory: str = setting("", "map directory; empty = <state_dir>/map")
    rate_hz: float = setting(10.0, "accumulation rate [Hz]; must divide estimation.rate_hz", 0.1, 100.0)
    flush_interval_s: float = setting(5.0, "tiles are written (off the event loop) this often [s]", 0.1, 3600.0)
    origin_lat: float = setting(math.nan, "field origin latitude [deg]; NaN = from the existing map, else the first fix", -90.0, 90.0, nan_ok=True)
    origin_lon: float = setting(math.nan, "field origin longitude [deg]; NaN = from the existing map, else the first fix", -180.0, 180.0, nan_ok=True)
    resolution_m: float = setting(0.5, "cell size of a new map [m]", 0.05, 100.0)
    max_fix_age_s: float = setting(0.5, "a position older than this is not mapped [s]", 0.01, 10.0)
    window_half_s: float = setting(10.0, "half width H of the centred map window; samples are mapped H seconds late [s] (tractionecu.mapping.sampler)", 0.1, 120.0)

    def __post_init__(self) -> None:
        validate(self, "map")
        if math.isnan(self.origin_lat) != math.isnan(self.origin_lon):
            raise ConfigError("map.origin_lat/map.origin_lon: give both or neither")


AXLE_TYPES = ("mfwd", "4wd", "2wd", "tracks")
"""Axle types with a slip band for ballasting (:data:`tractionecu.advice.rules.SLIP_BANDS`)."""


@dataclass(frozen=True)
class AdviceConfig:
    """Traction efficiency, the optimal slip and advice (:mod:`tractionecu.advice`); advice only, never acts."""

    enabled: bool = setting(True, "compute η, s* and the advice; send TECU_EstEfficiency (PGN 65315) at broadcast.rate_hz")
    axle_type: str = setting("mfwd", "axle type for the ballasting slip band: mfwd (8-12 %), 4wd (8-12 %), "
                                     "2wd (10-15 %), tracks (2-5 %)")
    slip_min: float = setting(math.nan, "lower end of the slip band [-]; NaN = the axle type's", 0.0, 1.0, nan_ok=True)
    slip_max: float = setting(math.nan, "upper end of the slip band [-]; NaN = the axle type's", 0.0, 1.0, nan_ok=True)
    distance_m: float = setting(100.0, "slip outside the band over this distance of pulling gives advice [m]", 1.0, 100000.0)
    eta_loss: float = setting(0.05, "efficiency below eta(s*) by more than this is far below the optimum [-]", 0.001, 1.0)
    eta_minutes: float = setting(2.0, "... for this long gives advice [min]", 0.1, 600.0)
    tyre_pressure_min_pa: float = setting(0.0, "lowest tyre pressure the tyre's load table allows for this "
                                               "machine [Pa]; 0 = no tyre pressure advice", 0.0, 1e6)
    max_sigma_s_star: float = setting(0.01, "s* is sent only with a standard error up to this [-]", 0.0001, 1.0)
    ballast_kg: float = setting(math.nan, "ballast the machine carries now [kg]; NaN = not declared (no amount of "
                                          "ballast to remove is given)", 0.0, 100000.0, nan_ok=True)
    max_mass_kg: float = setting(math.nan, "the machine's permissible total mass [kg] (registration document, "
                                           "operator's manual); ballast advised stays within it; NaN = not declared",
                                 100.0, 200000.0, nan_ok=True)
    max_front_axle_kg: float = setting(math.nan, "permissible load of the front axle [kg]; ballast advised keeps the "
                                                 "static axle load within it; NaN = not declared",
                                       10.0, 100000.0, nan_ok=True)
    max_rear_axle_kg: float = setting(math.nan, "permissible load of the rear axle [kg]; NaN = not declared",
                                      10.0, 100000.0, nan_ok=True)

    def settings(self) -> Any:
        """The advice's thresholds (:class:`~tractionecu.advice.rules.AdviceSettings`): every key of this table
        that names one of its fields (the rest, the tyre pressure now, are the vehicle's)."""
        from ..advice.rules import AdviceSettings

        names = {f.name for f in fields(AdviceSettings)}
        return AdviceSettings(**{f.name: getattr(self, f.name) for f in fields(self) if f.name in names})

    def __post_init__(self) -> None:
        validate(self, "advice")
        if self.axle_type not in AXLE_TYPES:
            raise ConfigError(f"advice.axle_type: {self.axle_type!r} is not one of {', '.join(AXLE_TYPES)}")
        if not (math.isnan(self.slip_min) or math.isnan(self.slip_max)) and self.slip_max <= self.slip_min:
            raise ConfigError(f"advice.slip_max = {self.slip_max} is not above advice.slip_min = {self.slip_min}")
        from ..advice.rules import SLIP_BANDS

        lo, hi = SLIP_BANDS[self.axle_type]
        if math.isnan(self.slip_min) != math.isnan(self.slip_max):
            # one end given: the other is the axle type's, and the band must still run upwards (slip_max 0.05
            # with an MFWD's 8 % made the band 8 %–5 % and advised ballast at 6.5 % slip)
            lo = lo if math.isnan(self.slip_min) else self.slip_min
            hi = hi if math.isnan(self.slip_max) else self.slip_max
            if hi <= lo:
                given = "slip_max" if math.isnan(self.slip_min) else "slip_min"
                raise ConfigError(f"advice.{given} = {self.slip_max if given == 'slip_max' else self.slip_min}: the "
                                  f"band with the {self.axle_type} axle type's other end is {lo:g}–{hi:g}, which "
                                  "does not run upwards; give both slip_min and slip_max")
        if 0.0 < self.tyre_pressure_min_pa < 2.0e4:
            raise ConfigError(f"advice.tyre_pressure_min_pa = {self.tyre_pressure_min_pa:g}: that is "
                              f"{self.tyre_pressure_min_pa / 1e5:.4f} bar; the key is in Pa "
                              f"({self.tyre_pressure_min_pa:g} kPa = {self.tyre_pressure_min_pa * 1e3:g}, "
                              f"{self.tyre_pressure_min_pa:g} bar = {self.tyre_pressure_min_pa * 1e5:g})")


@dataclass(frozen=True)
class WebConfig:
    """The read-only in-cab page (:mod:`tractionecu.web`)."""

    enabled: bool = setting(True, "serve the in-cab page (read-only: no write endpoints)")
    host: str = setting("127.0.0.1", "address to listen on: 127.0.0.1 (this computer only) or the cab "
                                     "display's network address (the systemd unit's IPAddressAllow= must allow it)")
    port: int = setting(8080, "TCP port (the systemd unit's SocketBindAllow= must allow it); 0 = any free port", 0, 65535)
    update_hz: float = setting(2.0, "updates pushed to each viewer [Hz]", 0.2, 5.0)
    max_viewers: int = setting(8, "viewers at once; more are refused", 1, 64)
    queue_updates: int = setting(4, "updates waiting for one viewer; a viewer that falls further behind is "
                                    "dropped [updates]", 1, 64)

    def __post_init__(self) -> None:
        validate(self, "web")
        if not self.host:
            raise ConfigError("web.host: must not be empty")


@dataclass(frozen=True)
class ServiceSection:
    """Process-wide settings."""

    state_dir: str = setting("", f"writable state directory; empty = ${STATE_DIR_ENV} (systemd) or ./{DEFAULT_STATE_DIR}")
    status_interval_s: float = setting(1.0, "STATUS= notification and status line interval [s]", 0.1, 3600.0)
    watchdog_behind_s: float = setting(2.0, "WATCHDOG=1 stops once the estimation loop has been behind its "
                                       "schedule (steps more than a broadcast period late, or skipped) this "
                                       "long; STATUS= says why [s]", 0.1, 600.0)

    def __post_init__(self) -> None:
        validate(self, "service")


@dataclass(frozen=True)
class ServiceConfig:
    """Everything ``tractionecu run`` needs; one dataclass per TOML table."""

    can: CanConfig = section(CanConfig, "the CAN bus")
    gps: GpsConfig = section(GpsConfig, "the GNSS receiver")
    estimation: EstimationConfig = section(EstimationConfig, "the estimation loop")
    sensors: SensorSpec = section(SensorSpec, "Sensor figures (R and input noise of the estimator).  A key set here "
                                              "overrides the same key of the vehicle file's [sensors]; the keys set "
                                              "in neither take the defaults shown.", partial=True)
    broadcast: BroadcastConfig = section(BroadcastConfig, "estimate broadcast and address claim")
    map: MapConfig = section(MapConfig, "the map writer")
    advice: AdviceConfig = section(AdviceConfig, "traction efficiency, optimal slip and advice")
    web: WebConfig = section(WebConfig, "the read-only in-cab page")
    service: ServiceSection = section(ServiceSection, "process-wide settings")
    signals: Mapping[str, Any] = table("the owner's messages onto the contract names: WheelSpeed_FL = "
                                       "\"DriveCtrl_3.WhlSpdFL\" or { signal = \"...\", scale = ... } "
                                       "(over the vehicle file's [signals])")

    def __post_init__(self) -> None:
        validate(self, "")
        base.signal_map(self.signals, "signals")          # the form; the names are checked against the DBCs
        for key, rate in (("broadcast.rate_hz", self.broadcast.rate_hz), ("map.rate_hz", self.map.rate_hz)):
            ratio = self.estimation.rate_hz / rate
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise ConfigError(
                    f"{key} = {rate} does not divide estimation.rate_hz = {self.estimation.rate_hz}"
                )

    def state_dir(self, env: Mapping[str, str] | None = None) -> Path:
        """The state directory: config, else ``$STATE_DIRECTORY`` (first entry), else ./tractionecu-state."""
        if self.service.state_dir:
            return Path(self.service.state_dir)
        env = os.environ if env is None else env
        sd = env.get(STATE_DIR_ENV, "")
        if sd:
            return Path(sd.split(":")[0])
        return Path(DEFAULT_STATE_DIR)

    def map_dir(self, env: Mapping[str, str] | None = None) -> Path:
        """The map directory: ``map.directory`` or ``<state_dir>/map``."""
        if self.map.directory:
            return Path(self.map.directory)
        return self.state_dir(env) / "map"

    def dbc_files(self) -> list[str]:
        """The owner's DBC files of ``can.dbc`` (empty entries dropped)."""
        return [p for p in self.can.dbc if p]

    def signal_mapping(self) -> dict[str, tuple[str, float]]:
        """The ``[signals]`` mapping in force: the vehicle file's ``[signals]`` (``estimation.vehicle``), the
        keys of this config's ``[signals]`` over it (:func:`~tractionecu.config.signal_map`)."""
        out = dict(base.load_signal_map(self.estimation.vehicle)) if self.estimation.vehicle else {}
        out.update(base.signal_map(self.signals, "signals"))
        return out

    def sensor_overrides(self) -> dict[str, Any]:
        """The ``[sensors]`` keys this config sets explicitly (:func:`~tractionecu.config.given_keys`)."""
        return {k: getattr(self.sensors, k) for k in sorted(given_keys(self.sensors))}

    def resolved_sensors(self) -> SensorSpec:
        """The sensor figures the estimator uses: this config's ``[sensors]`` keys over the
        ``[sensors]`` of ``estimation.vehicle`` over the defaults (reads the vehicle file)."""
        return resolve_sensors(self.estimation.vehicle or None, self.sensor_overrides())


def from_dict(data: Mapping[str, Any]) -> ServiceConfig:
    """Build a :class:`ServiceConfig` from parsed TOML tables."""
    return base.from_mapping(ServiceConfig, data, "")


def load_config(path: str | Path | None) -> ServiceConfig:
    """Load a service TOML file; ``None`` gives the defaults.  Raises ConfigError naming the file or key."""
    if path is None:
        return ServiceConfig()
    p = Path(path)
    data = base.load_toml(p, "config")
    try:
        return from_dict(data)
    except ConfigError as e:
        raise ConfigError(f"{p}: {e}") from None


def with_overrides(cfg: ServiceConfig, **sections: Mapping[str, Any]) -> ServiceConfig:
    """A copy of ``cfg`` with some keys replaced, e.g. ``with_overrides(cfg, can={"channel": "vcan0"})``.

    The keys ``cfg`` set explicitly stay explicit (they matter for ``[sensors]``).
    """
    data: dict[str, dict[str, Any]] = {}
    for f in fields(cfg):
        sec = getattr(cfg, f.name)
        data[f.name] = dict(sec) if isinstance(sec, Mapping) else {k: getattr(sec, k) for k in given_keys(sec)}
    for name, changes in sections.items():
        if name not in data:
            raise ConfigError(f"{name}: unknown table")
        data[name].update(changes)
    return from_dict(data)


def to_toml(cfg: ServiceConfig) -> str:
    """The config as TOML (every key, with its doc line), to store next to the outputs.

    ``[sensors]`` lists the keys the config sets; the others are written as
    comments, since the vehicle file's ``[sensors]`` may set them.
    """
    return "# tractionecu run: resolved configuration\n\n" + base.to_toml(cfg)
