//! Studies of a pipeline on a render set with a reference: `sweep` (parameter grids, timing, the
//! Pareto front, plots) and `ablate` (what each stage and feature buys), written by one table writer.

pub mod ablate;
pub mod sweep;
pub mod table;
