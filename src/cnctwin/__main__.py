"""``python -m cnctwin`` runs the command line."""

from cnctwin.cli import main

raise SystemExit(main())
