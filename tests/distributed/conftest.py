"""The distributed tests' shared helpers: this folder is on ``sys.path`` for every test
below it (pytest inserts a conftest's folder when it is not a package), so that
``from hostile import ...`` (:mod:`hostile`, the hostile-traffic generator) works from
``tests/distributed/web`` and ``tests/distributed/pool`` too."""
