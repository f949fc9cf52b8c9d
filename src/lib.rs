//! Host package of the top-level integration tests in `tests/`; it has no code of its own.
