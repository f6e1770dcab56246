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
    s = Settings()
    assert s.database_url == "sqlite:///./var/bodyhealth.db"
    assert (s.window_seconds, s.retention_seconds, s.worker_interval_seconds) == (30.0, 600.0, 5.0)
    assert (s.network_interval_cycles, s.baseline_repeat_k, s.alert_hysteresis_m) == (12, 3, 2)
    assert s.network_on_change is True
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
