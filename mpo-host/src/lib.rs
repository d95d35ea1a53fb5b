//! Host-side library of the `mpo` command.
