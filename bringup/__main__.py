"""Entry point of ``python -m bringup`` (what ``scripts/run`` runs)."""

from bringup.graph import main

raise SystemExit(main())
