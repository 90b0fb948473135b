"""The mission file format: the YAML schema and its defaults (:mod:`.schema`), the loader with its
error messages (:mod:`.load`), the shipped missions (:mod:`.examples`, ``examples/*.yaml``), the
scenario a mission draws for one seed (:mod:`.scenario`) and the code version stamped on every file
a run writes (:mod:`.version`).

The bottom room of :mod:`mission`: it imports no other room (pyproject.toml's import-linter
contracts, docs/design/architecture.md).
"""
