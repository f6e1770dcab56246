"""``python -m cli`` does what the ``bodyhealth`` console script does."""

from cli.main import main

raise SystemExit(main())
