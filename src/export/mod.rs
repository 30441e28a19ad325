//! Dataset exporters (LeRobot, RLDS, point clouds, MCAP).
//!
//! Every exporter has one shape: options -> `Writer::create` -> per-episode writes ->
//! `finish() -> Summary`, fed through the collection sink trait. Exporters never depend on the
//! simulator: they see episodes (arrays, strings, metadata) only. The first exporter lands with
//! the episode model (issue 4); this module is the place it goes.
