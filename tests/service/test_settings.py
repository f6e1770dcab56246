"""Settings: environment variables with the BODYHEALTH_ prefix, one cached object, validation."""

from __future__ import annotations

import pytest

from service.settings import Settings, get_settings, reset_settings


@pytest.fixture(autouse=True)
def _fresh_settings(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.chdir(tmp_path)  # no stray .env file
    reset_settings()
    yield
    reset_settings()


def test_defaults(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("BODYHEALTH_NETWORK_INTERVAL_CYCLES", raising=False)  # the suite's own (conftest)
    monkeypatch.delenv("BODYHEALTH_TRAINING_IDLE", raising=False)  # the suite's own (conftest)
    s = Settings()
    assert s.database_url == "sqlite:///./var/bodyhealth.db"
    assert (s.window_seconds, s.retention_seconds, s.worker_interval_seconds) == (30.0, 600.0, 5.0)
    assert (s.network_interval_cycles, s.baseline_repeat_k, s.alert_hysteresis_m) == (12, 3, 2)
    assert s.network_on_change is True
    assert (s.training_nice, s.training_idle) == (10, True)
    assert (s.queue_max_batches, s.host, s.port, s.max_request_bytes, s.log_json) == (
        1000,
        "127.0.0.1",
        8000,
        1_000_000,
        True,
    )


def test_environment_overrides_and_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BODYHEALTH_DATABASE_URL", "postgresql+psycopg://u@h/db")
    monkeypatch.setenv("bodyhealth_window_seconds", "12.5")
    monkeypatch.setenv("BODYHEALTH_LOG_JSON", "false")
    s = get_settings()
    assert (
        s.database_url == "postgresql+psycopg://u@h/db" and s.window_seconds == 12.5 and s.log_json is False
    )
    monkeypatch.setenv("BODYHEALTH_WINDOW_SECONDS", "20")
    assert get_settings() is s and get_settings().window_seconds == 12.5  # cached until reset
    reset_settings()
    assert get_settings().window_seconds == 20.0


def test_dotenv_file(tmp_path) -> None:
    (tmp_path / ".env").write_text("BODYHEALTH_PORT=9123\nOTHER_APP_SETTING=1\n")
    assert get_settings().port == 9123


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("WINDOW_SECONDS", "-1"),
        ("PORT", "70000"),
        ("QUEUE_MAX_BATCHES", "0"),
        ("RETENTION_SECONDS", "10"),
        ("ALERT_HYSTERESIS_M", "many"),
    ],
)
def test_bad_values_are_rejected_naming_the_field(
    monkeypatch: pytest.MonkeyPatch, name: str, value: str
) -> None:
    monkeypatch.setenv(f"BODYHEALTH_{name}", value)
    with pytest.raises(
        ValueError, match=name.lower() if name != "RETENTION_SECONDS" else "retention_seconds"
    ):
        get_settings()


def test_dask_settings_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    from service.cluster import ClusterOptions, embedded_workers

    s = Settings()
    assert (s.dask_enabled, s.dask_scheduler, s.dask_workers, s.dask_connect_timeout_seconds) == (
        True,
        None,
        None,
        5.0,
    )
    monkeypatch.setenv("BODYHEALTH_DASK_SCHEDULER", "  ")  # blank: the embedded cluster
    assert Settings().dask_scheduler is None
    monkeypatch.setenv("BODYHEALTH_DASK_SCHEDULER", "tcp://10.0.0.7:8786")
    monkeypatch.setenv("BODYHEALTH_DASK_WORKERS", "3")
    monkeypatch.setenv("BODYHEALTH_DASK_ENABLED", "false")
    s = Settings()
    assert (s.dask_scheduler, s.dask_workers, s.dask_enabled) == ("tcp://10.0.0.7:8786", 3, False)
    opts = ClusterOptions.from_settings(s)
    assert (opts.scheduler, opts.workers, opts.where) == (
        "tcp://10.0.0.7:8786",
        3,
        "Dask scheduler tcp://10.0.0.7:8786",
    )
    assert ClusterOptions().where == "embedded Dask cluster" and embedded_workers(4) == 3
    monkeypatch.setenv("BODYHEALTH_DASK_WORKERS", "0")
    with pytest.raises(ValueError, match="dask_workers"):
        Settings()


def test_an_explicit_zero_or_false_override_is_honoured() -> None:
    """A caller's 0 or False overrides the setting (``value or default`` would read it as unset)."""
    from service.settings import overridden

    s = Settings(confirm_timeout_seconds=30.0, network_on_change=True, imu_silent_seconds=2.0)
    assert overridden(s, "confirm_timeout_seconds", 0) == 0.0
    assert overridden(s, "network_on_change", False) is False
    assert overridden(s, "imu_silent_seconds", None) == 2.0
    assert overridden(s, "imu_silent_seconds", 0.25) == 0.25


def test_an_override_out_of_the_fields_bounds_is_refused_in_one_line(tmp_path) -> None:
    """The store's and the pipeline's overrides are checked as the settings are: an explicit 0 where the
    field must be positive is an error naming it, never the setting silently used instead."""
    from service.ingest.pipeline import Pipeline
    from service.store import Store

    url = f"sqlite:///{tmp_path / 'o.db'}"
    with pytest.raises(ValueError, match=r"^retention_seconds = 0: input should be greater than 0$"):
        Store(url, retention_seconds=0)
    store = Store(url, imu_silent_seconds=0.25, chunk_max_samples=1)
    try:
        assert (store.imu_silent_seconds, store.chunk_max_samples) == (0.25, 1)
        with pytest.raises(
            ValueError, match=r"^queue_max_batches = 0: input should be greater than or equal to 1$"
        ):
            Pipeline(store, [], queue_max_batches=0)
        assert Pipeline(store, [], queue_max_batches=1).queue_max_batches == 1
    finally:
        store.close()
