//! Criterion benchmarks of the trimctl hot paths (see `benches/*.rs`); this library holds the
//! seeded data generators they share.
