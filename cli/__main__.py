"""``python -m cli`` does what the ``bodyhealth`` console script does."""

from cli.main import main

if __name__ == "__main__":  # not when a spawned child process imports the main module again
    raise SystemExit(main())
