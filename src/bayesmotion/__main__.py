"""``python -m bayesmotion`` runs the command-line interface."""

from bayesmotion.app.cli import main

raise SystemExit(main())
