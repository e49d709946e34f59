"""The test suite (a package, so that `tests.helpers` and `tests.fit_reference` import cleanly)."""
