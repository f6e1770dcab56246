"""One module per ``bodyhealth`` subcommand; each exposes ``register(subparsers)``."""
