"""``python -m legoh_rl.envs.trails`` (see :mod:`legoh_rl.envs.trails.cli`)."""

from .cli import main

raise SystemExit(main())
