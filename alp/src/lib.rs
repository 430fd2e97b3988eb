//! Accidental light probes: losses, joint pose + lighting estimation, acquisition, evaluation and the `alp` CLI.
