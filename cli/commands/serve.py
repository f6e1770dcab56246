"""``bodyhealth serve``: API, dashboard, ingest and worker in one process (see :mod:`service.daemon`).

Listening on an address other machines can reach needs a token (docs/security.md): without one,
anyone on the network could approve baselines, acknowledge alerts and push frames. On loopback the
service stays open, as ``make run`` starts it.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing
import multiprocessing.util
import os
import sys
from pathlib import Path

__all__ = ["EXIT_NO_TOKEN", "register"]

#: Exit code of ``serve`` refusing a non-loopback address without a token (as argparse's usage errors).
EXIT_NO_TOKEN = 2


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve",
        help="run the service: REST API + dashboard, ingest and monitoring worker",
        description="Run the service until SIGTERM/SIGINT. Settings come from BODYHEALTH_* "
        "environment variables; the options below override them.",
    )
    p.add_argument(
        "--demo",
        action="store_true",
        help="simulate a farm of ur5e, paper-3 and quadruped in real time (x --speed)",
    )
    p.add_argument("--speed", type=float, default=1.0, help="demo farm speed, x real time (default 1)")
    p.add_argument(
        "--sensing",
        choices=("robot", "ideal"),
        help="how simulated farms sense their motion: robot (multi-rate, two clocks) or ideal "
        "(one clock); default: settings (BODYHEALTH_SENSING, robot)",
    )
    p.add_argument(
        "--source",
        action="append",
        default=[],
        metavar="SPEC",
        help="ingest source, e.g. farm:ur5e@2, replay:run.npz@10, rosbag:run.mcap@10, can:..., serial:... "
        "(repeatable)",
    )
    p.add_argument(
        "--port",
        type=int,
        help="HTTP port (default: settings, 8000); 0 takes a free one, announced on stdout once bound",
    )
    p.add_argument(
        "--host",
        help="HTTP host (default: settings, 127.0.0.1); any address but loopback needs "
        "BODYHEALTH_API_TOKEN or BODYHEALTH_API_TOKEN_FILE",
    )
    p.add_argument("--database-url", help="SQLAlchemy URL (default: settings, sqlite:///./var/bodyhealth.db)")
    p.add_argument("--commit-log", type=Path, help="append one JSON line per ingest commit here")
    p.add_argument("--text-logs", action="store_true", help="human log lines instead of JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from service.daemon import Daemon, demo_spec
    from service.log_config import configure_logging
    from service.settings import get_settings, is_loopback

    if not args.speed > 0:
        raise ValueError(f"--speed must be positive, got {args.speed}")
    update = {
        k: v
        for k, v in (
            ("port", args.port),
            ("host", args.host),
            ("database_url", args.database_url),
            ("sensing", getattr(args, "sensing", None)),
        )
        if v is not None
    }
    settings = get_settings().model_copy(update=update)
    if not is_loopback(settings.host) and settings.write_token() is None:
        print(
            f"bodyhealth serve: refusing to listen on {settings.host} without an API token: anyone who "
            "can reach it could change baselines, alerts and frames. Set BODYHEALTH_API_TOKEN=<token> "
            "or BODYHEALTH_API_TOKEN_FILE=<file holding it> (see docs/security.md), "
            "or listen on 127.0.0.1.",
            file=sys.stderr,
        )
        return EXIT_NO_TOKEN
    configure_logging(
        logging.DEBUG if args.verbose > 1 else logging.INFO,
        json_lines=settings.log_json and not args.text_logs,
    )
    specs = list(args.source)
    if args.demo:
        specs.insert(0, demo_spec(args.speed))
    log = logging.getLogger(__name__)
    if not specs:
        log.warning("no --source and no --demo: serving what the database holds")
    if settings.allowed_hosts is None and settings.host in ("0.0.0.0", "::"):
        log.warning(
            "listening on every address, but only requests for %s are answered; "
            "set BODYHEALTH_ALLOWED_HOSTS to the names clients use",
            ", ".join(settings.trusted_hosts()),
        )
    code = Daemon(settings, specs, commit_log=args.commit_log).serve()
    _leave_children(code)
    return code


def _leave_children(code: int) -> None:
    """Exit with ``code`` at once when child processes are still ending after the stop.

    The stop has ended every child (the cluster's workers are killed after their grace), but the kernel
    can take long to tear down a killed worker that holds torch's threads, and multiprocessing's exit
    hook joins every child without a timeout: at load 5 on 2 cores the process exited 16 to 21 s after
    "service stopped", all of it in that join (while at rest it takes 0.1 s). Nothing is left to do
    for them, so the process leaves without waiting; init reaps them. Leaving skips that hook, so its
    first step runs here: the finalizers of priority 0 unlink the semaphores of the cluster's queues,
    which the resource tracker would otherwise report as leaked on stderr."""
    left = multiprocessing.active_children()
    if not left:
        return
    logging.getLogger(__name__).info(
        "exiting without waiting for %d child process(es) still ending", len(left)
    )
    # The exit hook's own first step (a private helper: multiprocessing has no public call that runs the
    # finalizers without also joining the children).
    multiprocessing.util._run_finalizers(0)  # type: ignore[attr-defined]
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
