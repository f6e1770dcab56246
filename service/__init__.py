"""I/O around the science: settings, store, ingestors, worker, REST API, dashboard, CLI, metrics."""
