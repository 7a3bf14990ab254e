"""``python -m recon.replay``: :func:`recon.replay.cli.main`."""

from recon.replay.cli import main

raise SystemExit(main())
