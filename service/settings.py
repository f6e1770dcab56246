"""Service configuration: one :class:`Settings` object, read from the environment, behind a cached getter.

Every field can be set with an environment variable named ``BODYHEALTH_<FIELD>`` (case-insensitive),
e.g. ``BODYHEALTH_DATABASE_URL=postgresql+psycopg://user@host/db``, or from a ``.env`` file in the
working directory. Code asks :func:`get_settings` (cached, so the environment is read once); tests that
change the environment call :func:`reset_settings` afterwards. The security settings (tokens, allowed
hosts, the time-jump bound) are described in docs/security.md.

Example
-------
>>> s = Settings(database_url="sqlite:///:memory:", window_seconds=12)
>>> s.window_seconds, s.retention_seconds
(12.0, 600.0)
>>> try:
...     Settings(window_seconds=-1)
... except ValueError as err:
...     print(err.errors()[0]["loc"])
('window_seconds',)
"""

from __future__ import annotations

import ipaddress
import json
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, SecretStr, TypeAdapter, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from bodyschema.lever_pool import PoolOptions

__all__ = ["LOCAL_HOSTS", "Settings", "get_settings", "is_loopback", "overridden", "reset_settings"]

#: Host names every app answers to (``Host`` header), whatever the configuration adds.
LOCAL_HOSTS: tuple[str, ...] = ("localhost", "127.0.0.1", "::1", "[::1]", "testserver")


def is_loopback(host: str) -> bool:
    """True for an address only this machine can reach: ``localhost``, 127.0.0.0/8, ``::1``.

    >>> [is_loopback(h) for h in ("127.0.0.1", "[::1]", "localhost", "0.0.0.0", "::", "10.0.0.5")]
    [True, True, True, False, False, False]
    """
    host = host.strip().strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name: it may resolve to anything
        return False


class Settings(BaseSettings):
    """All tunables of the service. Times are seconds; ``*_t`` quantities elsewhere are device time."""

    model_config = SettingsConfigDict(
        env_prefix="BODYHEALTH_",
        env_file=".env",
        env_file_encoding="utf-8",
        extra="ignore",
        hide_input_in_errors=True,  # an error must not echo a token back
    )

    # ---------------------------------------------------------------- storage
    database_url: str = Field(
        "sqlite:///./var/bodyhealth.db",
        description="SQLAlchemy URL; SQLite file (WAL) by default, PostgreSQL as postgresql+psycopg://...",
    )
    window_seconds: float = Field(30.0, gt=0, description="device-time window the worker learns from")
    retention_seconds: float = Field(600.0, gt=0, description="frames older than this (device time) go")
    imu_silent_seconds: float = Field(
        1.0, gt=0, description="an IMU not heard for this long (device time) counts as silent"
    )
    clock_reset_seconds: float = Field(
        10.0,
        gt=0,
        description="a batch whose newest stamp lies more than this (device time) behind the robot's "
        "newest frame means its clock went back (a restart): a new epoch starts (docs/service.md)",
    )
    chunk_max_samples: int = Field(1000, ge=1, description="most samples the store puts in one chunk row")
    prune_interval_seconds: float = Field(10.0, gt=0, description="wall time between retention prunes")
    topology_history_keep: int = Field(
        50,
        ge=1,
        description="newest learned topologies kept per robot and method; older ones are kept only "
        "where they differ from their predecessor (a change)",
    )
    max_robots: int = Field(
        1000, ge=1, description="most robots the store registers; frames of a further new robot are refused"
    )

    # ----------------------------------------------------------------- worker
    worker_interval_seconds: float = Field(5.0, gt=0)
    network_interval_cycles: int = Field(
        12,
        ge=0,
        description="retrain every robot's sensor networks every N worker cycles (12 at the default "
        "5 s interval: once a minute); 0 = never, unless asked",
    )
    network_on_change: bool = Field(
        True,
        description="retrain a robot's sensor networks at once when the fast method's diff against the "
        "baseline shows a new finding (needs network_interval_cycles > 0)",
    )
    network_heldout_check: bool = Field(
        True,
        description="test the sensor networks' tree against its rival answers on held-out data before a "
        "part counts as decided (bodyschema.network_confidence); parts the data do not decide are then "
        "undetermined rather than the networks' ranking (false: the ranking, untested)",
    )
    kinematics_interval_cycles: int = Field(
        6,
        ge=0,
        description="estimate every robot's joint axes and IMU lever arms every N worker cycles (6 at "
        "the default 5 s interval and 30 s window: each estimate on a window of its own) and compare "
        "them with the geometry learned on its baseline (drift alerts); also once its data has run N "
        "worker intervals past the last, when cycles overrun; 0 = never",
    )
    kinematics_accelerometer_frame: bool = Field(
        True,
        description="estimate the geometry's joint axes in each accelerometer's frame, gyros and "
        "accelerometers together, so that the gyros' sensitivity errors do not lean the axes the lever "
        "arms are fitted about (a UR5e wrist IMU's lever arm then scatters 1 mm between windows, not 4 "
        "to 5, and its 5 mm slides are found; docs/kinematics.md); false: the axes the gyros read, at "
        "about half the CPU of a fleet's hour",
    )
    kinematics_pool_base: int = Field(
        PoolOptions.n_base,
        ge=5,
        description="geometry estimates whose lever arms, pooled, stand for the baseline's when slides "
        "of an IMU on its link are judged (at the default pace: 40 minutes after the baseline)",
    )
    kinematics_pool_recent: int = Field(
        PoolOptions.n_recent,
        ge=3,
        description="newest geometry estimates whose lever arms, pooled, are compared with the baseline's "
        "(the newest k of them, for every k up to this)",
    )
    baseline_repeat_k: int = Field(3, ge=1, description="equal topologies that make a baseline")
    alert_hysteresis_m: int = Field(2, ge=1, description="cycles before a finding alerts")
    confirm_timeout_seconds: float = Field(
        0.0,
        ge=0,
        description="wall time a pending structural alert waits for the sensor networks' confirmation "
        "before the fast screen's finding stands as an unconfirmed alert; 0 = derived: 3 x the "
        "robot's expected network retrain time as the training queue reports it, at least 2 worker "
        "intervals and at most confirm_timeout_max_seconds",
    )
    confirm_timeout_max_seconds: float = Field(
        150.0,
        gt=0,
        description="upper bound of the derived confirm_timeout_seconds. The budget: 5 minutes from "
        "damage to alert, less the fast screen's time to see a change (a 30 s window and 2 cycles of "
        "hysteresis: up to 90 s when cycles slow to 15 s on a loaded machine), less 4 slow cycles for "
        "the timeout to be noticed and stored; so damage is an alert within 5 minutes even when "
        "training gets no CPU",
    )
    baseline_unconfirmed_cycles: int = Field(
        6,
        ge=0,
        description="cycles the fast screen's body must hold, with no network answer from a window "
        "that ended after it first held, before it is adopted as a baseline marked fast-unconfirmed "
        "(twice the baseline_repeat_k an agreed baseline needs); 0 = wait for the networks",
    )
    baseline_unconfirmed_seconds: float = Field(
        60.0,
        ge=0,
        description="least wall time a complete streak waits for the sensor networks before its body is "
        "adopted fast-unconfirmed (with baseline_unconfirmed_cycles, both must hold). Counted in wall "
        "time, not cycles, so that a loaded machine's slow cycles do not stretch it: at the default 30 s "
        "window and 3 repeats a robot has a baseline about 2 minutes after its first frame even when "
        "training gets no CPU",
    )
    worker_min_rest_seconds: float = Field(
        1.0,
        ge=0,
        description="least wall time between the end of a worker cycle and the start of the next: a "
        "cycle that overran its interval skips the ticks it missed instead of running back to back",
    )
    retrain_min_interval_seconds: float = Field(
        30.0,
        ge=0,
        description="wall time between two accepted retrain requests of one robot (more are 429); "
        "0 = no limit",
    )
    max_retrains_queued: int | None = Field(
        None,
        ge=1,
        description="most retrains submitted to the training cluster at once (queued there or running); "
        "more wait in the service, oldest want first and round-robin over robots, and a retrain request "
        "that would add one is 429. Unset: twice the cluster's worker threads (one training and one "
        "ready behind it per thread, so no thread idles between two worker cycles)",
    )
    retrain_max_wall_seconds: float = Field(
        900.0,
        gt=0,
        description="the longest one sensor-network retrain is expected to take on the cluster, wall time "
        "(measured: 107 CPU s on a busy 2-core machine; the idle scheduling class stretches the wall "
        "time). A submitted retrain's window is kept from retention for (max_retrains_queued + 1) times "
        "this, so a lost task cannot keep frames forever",
    )

    # --------------------------------------------------------------- training
    dask_enabled: bool = Field(
        True,
        description="run the sensor-network retrains as Dask distributed tasks (docs/service.md, "
        "Training on Dask); false = in the worker thread, as the offline tools do",
    )
    dask_scheduler: str | None = Field(
        None,
        description="address of an existing Dask scheduler (tcp://host:port); unset: the service starts "
        "an embedded LocalCluster on the first retrain",
    )
    dask_workers: int | None = Field(
        None, ge=1, description="worker processes of the embedded cluster (unset: CPU count - 1, at least 1)"
    )
    dask_connect_timeout_seconds: float = Field(
        5.0, gt=0, description="how long one attempt to reach the scheduler may take before it is retried"
    )
    training_nice: int = Field(
        10,
        ge=0,
        le=19,
        description="nice value the embedded cluster's retrains run at (Linux), so on a small machine "
        "they yield the CPU to the API and ingest; 0 = as the service; an external cluster's workers "
        "are left as they are",
    )
    training_idle: bool = Field(
        True,
        description="the embedded cluster's retrains run in Linux's idle scheduling class: any thread "
        "of the API or ingest that wakes takes their core at once (a nice value alone lets them "
        "finish their time slice first); an external cluster's workers are left as they are",
    )

    # ----------------------------------------------------------------- ingest
    queue_max_batches: int = Field(1000, ge=1, description="bounded ingest queue (backpressure)")
    ingest_commit_interval_seconds: float = Field(
        1.0,
        ge=0,
        description="while frames stream, the ingest writer commits at most this often, so chunks are "
        "big enough that writes are not amplified (docs/bench/writes.md); 0 = commit what is queued",
    )
    queue_put_timeout_seconds: float = Field(
        1.0, ge=0, description="how long a full queue blocks a reader before the batch is dropped"
    )
    imu_filter_delay_ms: float | None = Field(
        None,
        ge=0,
        le=100,
        description="stated group delay of the IMUs' on-chip low-pass, ms (MPU-6050 DLPF_CFG 3: 4.8, "
        "docs/design.md, 'Facts the error models use'); taken out of the estimated IMU lag to report "
        "the clock skew alone. Unset: "
        "the farm's sensing preset's when the service runs the farm, else 0 (skew_ms is then the lag)",
    )
    farm_seed: int = Field(0, description="seed of the simulated farm")
    sensing: str = Field(
        "robot",
        description="how the simulated farm senses and stamps its motion: 'robot' (multi-rate encoders "
        "and IMUs on two clocks, as a real robot logs them), 'ideal' (one clock, exact velocities) or "
        "a JSON object of simulators.sensing.SensingOptions",
    )

    # -------------------------------------------------------------------- API
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    max_request_bytes: int = Field(1_000_000, ge=1)
    api_cache_seconds: float = Field(
        1.0,
        ge=0,
        description="a read route's answer is reused while nothing was committed, for at most this long "
        "(the bound for writers in other processes); 0 = render every request",
    )
    log_json: bool = True
    interpreter_switch_ms: float = Field(
        1.0,
        gt=0,
        le=100,
        description="how long a thread of the service's interpreter may keep it while another waits "
        "(sys.setswitchinterval). A request gives the interpreter up at every socket and database "
        "call and waits up to this long to get it back while the farm, ingest or worker threads "
        "compute (docs/alert-latency.md); Python's default is 5 ms",
    )

    # --------------------------------------------------------------- security
    api_token: SecretStr | None = Field(
        None, description="bearer token every mutating request must carry (unset: no token needed)"
    )
    api_token_file: Path | None = Field(
        None, description="file holding the bearer token (content stripped); instead of api_token"
    )
    api_read_token: SecretStr | None = Field(
        None, description="bearer token GET routes of /api/v1 need (either token does); needs api_token"
    )
    allowed_hosts: Annotated[list[str] | None, NoDecode] = Field(
        None,
        description="Host header values the API answers (comma-separated or a JSON list; '*' = any); "
        "unset: localhost, 127.0.0.1, ::1, testserver and the bind host",
    )
    read_token_required: bool | None = Field(
        None,
        description="reads of robot data (every GET under /api/v1) need a bearer token (the read or the "
        "write token); unset: on whenever a token is configured",
    )
    allowed_origins: Annotated[list[str] | None, NoDecode] = Field(
        None,
        description="origins (scheme://host[:port]) besides the service's own that may send mutating "
        "requests, e.g. the public address of a TLS proxy in front (comma-separated or a JSON list)",
    )
    max_joints_per_robot: int = Field(
        256, ge=1, description="most joints one robot may have, in one batch and registered in all"
    )
    max_imus_per_robot: int = Field(
        256, ge=1, description="most IMUs one robot may have, in one batch and registered in all"
    )
    max_time_jump_seconds: float = Field(
        1e6,
        gt=0,
        description="frames pushed over the API may lie at most this far (device time) ahead of the "
        "robot's last stored frame",
    )

    @field_validator("api_token", "api_read_token", mode="before")
    @classmethod
    def _blank_token_is_unset(cls, v: object) -> object:
        # An empty variable (BODYHEALTH_API_TOKEN=) reads as "no token", never as the empty token.
        if isinstance(v, str) and not v.strip():
            return None
        return v.strip() if isinstance(v, str) else v

    @field_validator("dask_scheduler", mode="before")
    @classmethod
    def _blank_scheduler_is_unset(cls, v: object) -> object:
        # BODYHEALTH_DASK_SCHEDULER= reads as "embedded cluster", never as an address
        if isinstance(v, str):
            return v.strip() or None
        return v

    @field_validator("allowed_hosts", "allowed_origins", mode="before")
    @classmethod
    def _split_hosts(cls, v: object) -> object:
        if isinstance(v, str):
            v = v.strip()
            if v.startswith("["):
                return json.loads(v)
            return [h.strip() for h in v.split(",") if h.strip()]
        return v

    @field_validator("allowed_hosts")
    @classmethod
    def _host_patterns(cls, v: list[str] | None) -> list[str] | None:
        for h in v or ():
            if h != "*" and "*" in (h[2:] if h.startswith("*.") else h):
                raise ValueError(f"allowed host {h!r}: a wildcard is '*' alone or '*.domain'")
        return v

    def write_token(self) -> str | None:
        """The token mutating requests need: ``api_token``, or the stripped content of ``api_token_file``.

        Raises ``ValueError`` when both are set or the file cannot be read or is empty: a
        misconfigured token must stop the service, never leave it open."""
        if self.api_token_file is None:
            return self.api_token.get_secret_value() if self.api_token is not None else None
        if self.api_token is not None:
            raise ValueError("set api_token or api_token_file, not both")
        try:
            token = self.api_token_file.read_text(encoding="utf-8").strip()
        except OSError as err:
            raise ValueError(f"api_token_file {str(self.api_token_file)!r}: {err.strerror}") from None
        if not token:
            raise ValueError(f"api_token_file {str(self.api_token_file)!r} is empty")
        return token

    @property
    def imu_filter_delay(self) -> float | None:
        """``imu_filter_delay_ms`` in seconds, as the estimators take it (None: not stated)."""
        return None if self.imu_filter_delay_ms is None else 1e-3 * self.imu_filter_delay_ms

    @property
    def pool_options(self) -> PoolOptions:
        """How many geometry estimates the lever-arm pools of slide judgements hold, as the worker
        and the API's drift both read them."""
        return PoolOptions(n_base=self.kinematics_pool_base, n_recent=self.kinematics_pool_recent)

    def read_token(self) -> str | None:
        """The extra token GET routes accept (they accept the write token too); None when unset."""
        return self.api_read_token.get_secret_value() if self.api_read_token is not None else None

    def trusted_hosts(self) -> list[str]:
        """The ``Host`` header values the app accepts: ``allowed_hosts`` when set, else the local names
        plus the bind host (unless it binds every address, which names no host)."""
        if self.allowed_hosts is not None:
            return list(self.allowed_hosts)
        hosts = list(LOCAL_HOSTS)
        if self.host not in ("0.0.0.0", "::", "") and self.host not in hosts:
            hosts.append(self.host)
            if ":" in self.host and not self.host.startswith("["):  # IPv6: Host carries it bracketed
                hosts.append(f"[{self.host}]")
        return hosts

    @field_validator("sensing")
    @classmethod
    def _known_sensing(cls, v: str) -> str:
        v = v.strip()
        if v in ("robot", "ideal"):
            return v
        from simulators.sensing import resolve_sensing  # only for a JSON spec: keeps the import light

        resolve_sensing(v)  # raises ValueError saying what is wrong
        return v

    @model_validator(mode="after")
    def _tokens_consistent(self) -> Settings:
        token = self.write_token()  # raises for a missing or empty token file
        if self.api_read_token is not None and token is None:
            raise ValueError(
                "api_read_token needs api_token (or api_token_file): without one, mutating routes "
                "would be open while reads are closed"
            )
        if self.read_token_required and token is None:
            raise ValueError("read_token_required needs api_token (or api_token_file)")
        if self.read_token_required is False and self.api_read_token is not None:
            raise ValueError("api_read_token is set but read_token_required is false: unset one of them")
        return self

    def reads_need_token(self) -> bool:
        """Whether GET routes of ``/api/v1`` need a bearer token: ``read_token_required``, by default
        on whenever a token is configured."""
        if self.read_token_required is not None:
            return self.read_token_required
        return self.write_token() is not None

    @model_validator(mode="after")
    def _window_fits_retention(self) -> Settings:
        if self.window_seconds > self.retention_seconds:
            raise ValueError(
                f"window_seconds ({self.window_seconds}) must not exceed retention_seconds "
                f"({self.retention_seconds}): the window would read pruned frames"
            )
        return self


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings, read from the environment on first use."""
    return Settings()


def overridden(settings: Settings, name: str, value: Any) -> Any:
    """Field ``name`` of ``settings``, unless a caller's ``value`` overrides it (None: no override).

    An explicit 0 or False is an override like any other, never read as "unset" (as ``value or
    default`` would); it is checked against the field's own bounds, and one out of them raises
    ``ValueError`` naming the field.

    >>> overridden(Settings(), "retention_seconds", None) == Settings().retention_seconds
    True
    >>> overridden(Settings(), "network_on_change", False)
    False
    """
    if value is None:
        return getattr(settings, name)
    info = Settings.model_fields[name]
    kind = Annotated[(info.annotation, *info.metadata)] if info.metadata else info.annotation
    try:
        return TypeAdapter(kind).validate_python(value)
    except ValidationError as err:
        raise ValueError(f"{name} = {value!r}: {err.errors()[0]['msg'].lower()}") from None


def reset_settings() -> None:
    """Forget the cached settings so the next :func:`get_settings` re-reads the environment."""
    get_settings.cache_clear()
