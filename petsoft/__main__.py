"""``python -m petsoft``: the ``petsoft`` command (:mod:`petsoft.cli.main`)."""

from petsoft.cli.main import main

raise SystemExit(main())
