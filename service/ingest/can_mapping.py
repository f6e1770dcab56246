"""Which DBC signal carries which joint position or IMU axis: the ``can`` section of a device config.

A robot integrator with their own DBC writes a device config like this (``docs/wire-formats.md``)::

    {"robot": "rover", "period_s": 0.005,
     "joints": ["hip", "knee"], "imus": ["thigh_imu"],
     "can": {"dbc": "rover.dbc",
             "counter": {"signal": "SeqCnt", "bits": 8},
             "joints": {"hip": "EncHip.Angle", "knee": "EncKnee.Angle"},
             "imus": {"thigh_imu": {"acc": ["ImuA.AccX", "ImuA.AccY", "ImuA.AccZ"],
                                    "gyro": ["ImuG.RateX", "ImuG.RateY", "ImuG.RateZ"]}},
             "units": {"q": 0.017453292519943295, "acc": 9.80665, "gyro": 0.017453292519943295}}}

``units`` multiplies the DBC's physical value into the contract units (rad, m/s², rad/s); here the
DBC speaks degrees and g. Every mapped message must carry the counter signal. Without ``joints``/``imus``
in the ``can`` section the project layout (:mod:`can_layout`) is used, in config order (``"layout":
"fd"`` picks its CAN FD variant); without ``dbc`` the project DBC.

A multi-rate device (``"streams"`` in its config) maps one more signal per stream, the stream's time
stamp: ``"stamps": {"encoders": "EncTime.Stamp", "imus": "ImuTime.Stamp"}`` (the project layout maps
its ``ENCODER_STAMP``/``IMU_STAMP`` frames by itself). :meth:`SignalMap.for_streams` then gives one map
per stream; a message may feed only one of them, since each stream counts its own samples.

Example
-------
>>> from service.ingest.device import DeviceConfig
>>> sm = SignalMap.for_config(DeviceConfig("r1", 0.01, ("j1", "j2", "j3"), ("imu0",)))
>>> sorted(hex(i) for i in sm.by_id), sm.n_frames
(['0x100', '0x180', '0x80', '0x81'], 4)
"""

from __future__ import annotations

from dataclasses import dataclass

import cantools
from cantools.database.can import Database, Message

from service.ingest.can_layout import load_project_database, project_signal_map
from service.ingest.device import STREAMS, DeviceConfig, DeviceConfigError, StreamSpec

__all__ = ["FrameRoute", "SignalMap", "load_dbc"]

Q, ACC, GYRO, STAMP = 0, 1, 2, 3


@dataclass(frozen=True)
class FrameRoute:
    """Where the signals of one frame id go: (signal, kind, index, axis, factor) per mapped signal."""

    message: Message
    targets: tuple[tuple[str, int, int, int, float], ...]
    joints: tuple[int, ...]
    imus: tuple[int, ...]


def load_dbc(path: str | None) -> Database:
    """The user's DBC at ``path``, or the project DBC when ``path`` is None."""
    if path is None:
        return load_project_database()
    try:
        db = cantools.database.load_file(path, database_format="dbc", strict=False)
    except (OSError, cantools.database.UnsupportedDatabaseFormatError) as err:
        raise DeviceConfigError(f"{path}: cannot read DBC ({err})") from err
    assert isinstance(db, Database)
    return db


class _Router:
    """The routes a :class:`SignalMap` collects while it resolves its section against the DBC."""

    def __init__(self, db: Database, counter_signal: str, factor: dict[int, float]) -> None:
        self.db, self.counter_signal, self.factor = db, counter_signal, factor
        self.routes: dict[int, list] = {}
        self.joints_of: dict[int, set[int]] = {}
        self.imus_of: dict[int, set[int]] = {}
        self.messages: dict[int, Message] = {}

    def resolve(self, ref: str) -> Message:
        """The message of ``ref`` ("Message.signal"), checked to carry the signal and the counter."""
        mname, _, sname = str(ref).partition(".")
        try:
            msg = self.db.get_message_by_name(mname)
        except KeyError:
            raise DeviceConfigError(f"CAN mapping: no message {mname!r} in the DBC") from None
        names = {s.name for s in msg.signals}
        if sname not in names:
            raise DeviceConfigError(f"CAN mapping: message {mname!r} has no signal {sname!r}")
        if self.counter_signal not in names:
            raise DeviceConfigError(
                f"CAN mapping: message {mname!r} lacks the counter signal {self.counter_signal!r}"
            )
        return msg

    def add(self, ref: str, kind: int, index: int, axis: int) -> int:
        """Route signal ``ref`` to ``kind``'s array at ``index``, ``axis``; returns its frame id."""
        msg = self.resolve(ref)
        self.routes.setdefault(msg.frame_id, []).append(
            (ref.partition(".")[2], kind, index, axis, self.factor[kind])
        )
        self.messages[msg.frame_id] = msg
        return msg.frame_id

    def add_imu(self, name: str, k: int, spec: object) -> frozenset[int]:
        """Route IMU ``name``'s six signals (``spec``: 'acc' and 'gyro' lists); returns its frame ids."""
        if not (isinstance(spec, dict) and all(len(spec.get(key, ())) == 3 for key in ("acc", "gyro"))):
            raise DeviceConfigError(f"CAN mapping: IMU {name!r} needs 'acc' and 'gyro' lists of 3 signals")
        fids = set()
        for kind, key in ((ACC, "acc"), (GYRO, "gyro")):
            for axis, ref in enumerate(spec[key]):
                fid = self.add(ref, kind, k, axis)
                fids.add(fid)
                self.imus_of.setdefault(fid, set()).add(k)
        return frozenset(fids)


class SignalMap:
    """Resolved routing from frame ids to the joint/IMU arrays, checked against the DBC.

    A map of one stream of a multi-rate device also routes that stream's ``stamp`` signal (section key
    ``"stamp"``); :attr:`stream` then holds the stream's period and tick, and :attr:`stamp_frames` the
    id carrying the stamp."""

    def __init__(
        self, db: Database, config: DeviceConfig, section: dict, stream: StreamSpec | None = None
    ) -> None:
        self.config = config
        self.stream = stream
        counter = section.get("counter", {})
        self.counter_signal = str(counter.get("signal", "counter"))
        self.counter_bits = int(counter.get("bits", 16))
        units = section.get("units", {})
        factor = {
            Q: float(units.get("q", 1.0)),
            ACC: float(units.get("acc", 1.0)),
            GYRO: float(units.get("gyro", 1.0)),
        }
        jmap: dict = section.get("joints", {})
        imap: dict = section.get("imus", {})
        missing = [j for j in config.joints if j not in jmap] + [i for i in config.imus if i not in imap]
        unknown = [n for n in jmap if n not in config.joints] + [n for n in imap if n not in config.imus]
        if missing or unknown:
            raise DeviceConfigError(f"CAN mapping: names without a signal {missing}, unknown names {unknown}")
        router = _Router(db, self.counter_signal, factor)
        for j, name in enumerate(config.joints):
            fid = router.add(jmap[name], Q, j, 0)
            router.joints_of.setdefault(fid, set()).add(j)
        self.imu_frames: list[frozenset[int]] = [
            router.add_imu(name, k, imap[name]) for k, name in enumerate(config.imus)
        ]
        self.stamp_frames: frozenset[int] = frozenset()
        #: bit width, scale and offset of the stamp signal (raw ticks = (value - offset) / scale)
        self.stamp_bits, self.stamp_scale, self.stamp_offset = 0, 1.0, 0.0
        if "stamp" in section:
            self._route_stamp(router, str(section["stamp"]))
        self._messages: dict[int, Message] = router.messages
        self.by_id: dict[int, FrameRoute] = {
            fid: FrameRoute(
                router.messages[fid],
                tuple(t),
                tuple(sorted(router.joints_of.get(fid, ()))),
                tuple(sorted(router.imus_of.get(fid, ()))),
            )
            for fid, t in router.routes.items()
        }
        self.joint_frames = frozenset(router.joints_of)
        self.n_frames = len(self.by_id)

    def _route_stamp(self, router: _Router, ref: str) -> None:
        """Route the stream's ``stamp`` signal ``ref`` ("Message.signal") and keep its width and scale."""
        msg = router.resolve(ref)
        sig = msg.get_signal_by_name(ref.partition(".")[2])
        if sig.is_float or sig.length < 8:
            raise DeviceConfigError(f"CAN mapping: stamp {ref!r} must be an integer signal of 8+ bits")
        self.stamp_bits, self.stamp_scale, self.stamp_offset = (
            int(sig.length),
            float(sig.scale),
            float(sig.offset),
        )
        router.routes.setdefault(msg.frame_id, []).append((sig.name, STAMP, 0, 0, 1.0))
        router.messages[msg.frame_id] = msg
        self.stamp_frames = frozenset({msg.frame_id})

    @classmethod
    def for_config(cls, config: DeviceConfig, db: Database | None = None) -> SignalMap:
        """Resolve ``config.extra['can']`` (or the project layout) against its DBC."""
        section = dict(config.extra.get("can") or {})
        if db is None:
            db = load_dbc(section.get("dbc"))
        if "joints" not in section and "imus" not in section:
            layout = project_signal_map(config.joints, config.imus, str(section.get("layout", "classic")))
            section = {**layout, **{k: v for k, v in section.items() if k not in layout}}
        return cls(db, config, section)

    @classmethod
    def for_streams(cls, config: DeviceConfig, db: Database | None = None) -> tuple[SignalMap, SignalMap]:
        """The encoder stream's map and the IMU stream's map of a multi-rate ``config``.

        >>> cfg = DeviceConfig("r", 0.01, ("j1",), ("imu0",),
        ...                    {"streams": {"encoders": {"period_s": 0.004}, "imus": {"period_s": 0.01}}})
        >>> enc, imu = SignalMap.for_streams(cfg)
        >>> sorted(hex(i) for i in enc.by_id), sorted(hex(i) for i in imu.by_id)
        (['0x78', '0x80'], ['0x100', '0x180', '0x79'])
        """
        streams = config.streams
        if streams is None:
            raise DeviceConfigError("not a multi-rate device config (no 'streams' section)")
        section = dict(config.extra.get("can") or {})
        if db is None:
            db = load_dbc(section.get("dbc"))
        if "joints" not in section and "imus" not in section:
            layout = project_signal_map(
                config.joints, config.imus, str(section.get("layout", "classic")), streams=True
            )
            section = {**layout, **{k: v for k, v in section.items() if k not in layout}}
        stamps = section.get("stamps")
        if not (isinstance(stamps, dict) and all(isinstance(stamps.get(n), str) for n in STREAMS)):
            raise DeviceConfigError(
                "CAN mapping of a multi-rate device needs 'stamps': {'encoders': 'MSG.signal', "
                "'imus': 'MSG.signal'}"
            )
        base = {k: v for k, v in section.items() if k not in ("joints", "imus", "stamps")}
        enc_cfg = DeviceConfig(config.robot, streams["encoders"].period_s, config.joints, ())
        imu_cfg = DeviceConfig(config.robot, streams["imus"].period_s, (), config.imus)
        enc = cls(
            db,
            enc_cfg,
            {**base, "joints": section.get("joints", {}), "stamp": stamps["encoders"]},
            streams["encoders"],
        )
        imu = cls(
            db, imu_cfg, {**base, "imus": section.get("imus", {}), "stamp": stamps["imus"]}, streams["imus"]
        )
        shared = sorted(set(enc.by_id) & set(imu.by_id))
        if shared:
            raise DeviceConfigError(
                f"CAN mapping: frame ids {[hex(i) for i in shared]} carry both encoder and IMU signals; "
                "a multi-rate device sends each stream in frames of its own"
            )
        return enc, imu
