"""Service configuration: one :class:`Settings` object, read from the environment, behind a cached getter.

Every field can be set with an environment variable named ``BODYHEALTH_<FIELD>`` (case-insensitive),
e.g. ``BODYHEALTH_DATABASE_URL=postgresql+psycopg://user@host/db``, or from a ``.env`` file in the
working directory. Code asks :func:`get_settings` (cached, so the environment is read once); tests that
change the environment call :func:`reset_settings` afterwards.

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

from functools import lru_cache

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Settings", "get_settings", "reset_settings"]


class Settings(BaseSettings):
    """All tunables of the service. Times are seconds; ``*_t`` quantities elsewhere are device time."""

    model_config = SettingsConfigDict(
        env_prefix="BODYHEALTH_", env_file=".env", env_file_encoding="utf-8", extra="ignore"
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
    chunk_max_samples: int = Field(1000, ge=1, description="most samples the store puts in one chunk row")
    prune_interval_seconds: float = Field(10.0, gt=0, description="wall time between retention prunes")

    # ----------------------------------------------------------------- worker
    worker_interval_seconds: float = Field(5.0, gt=0)
    network_interval_cycles: int = Field(
        0, ge=0, description="0 = never run the networks; N = every N cycles"
    )
    baseline_repeat_k: int = Field(3, ge=1, description="equal topologies that make a baseline")
    alert_hysteresis_m: int = Field(2, ge=1, description="cycles before a finding alerts")

    # ----------------------------------------------------------------- ingest
    queue_max_batches: int = Field(1000, ge=1, description="bounded ingest queue (backpressure)")
    queue_put_timeout_seconds: float = Field(
        1.0, ge=0, description="how long a full queue blocks a reader before the batch is dropped"
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
    log_json: bool = True

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


def reset_settings() -> None:
    """Forget the cached settings so the next :func:`get_settings` re-reads the environment."""
    get_settings.cache_clear()
