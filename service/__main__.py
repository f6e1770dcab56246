"""``python -m service`` does what the ``bodyhealth`` console script does."""

from service.cli import main

raise SystemExit(main())
