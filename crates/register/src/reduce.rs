//! Deterministic parallel reductions: per-chunk partial sums computed in parallel over fixed
//! chunk boundaries, then added in chunk order. The result is the same to the bit for any number
//! of threads.

use rayon::prelude::*;

/// Items per chunk. Fixed: the chunk boundaries, and so the rounding, never depend on threads.
pub const CHUNK: usize = 2048;

/// Sums `term(i)` for `i in 0..n` with partial sums per [`CHUNK`] computed in parallel and added
/// in order. `zero` is the additive identity; `add` adds a term into an accumulator.
pub fn chunked_sum<A, F, G>(n: usize, zero: A, fold: F, add: G) -> A
where
    A: Clone + Send + Sync,
    F: Fn(&mut A, usize) + Sync,
    G: Fn(&mut A, &A),
{
    let chunks = n.div_ceil(CHUNK);
    let partials: Vec<A> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut acc = zero.clone();
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                fold(&mut acc, i);
            }
            acc
        })
        .collect();
    let mut total = zero;
    for p in &partials {
        add(&mut total, p);
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_bits_on_one_and_many_threads() {
        let values: Vec<f64> = (0..100_000)
            .map(|i| (f64::from(i) * 0.37).sin() * 1e3)
            .collect();
        let sum = || chunked_sum(values.len(), 0.0, |a, i| *a += values[i], |a, b| *a += b);
        let many = sum();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(sum);
        assert_eq!(many.to_bits(), one.to_bits());
        let exact: f64 = values.iter().sum();
        assert!((many - exact).abs() < 1e-6);
    }
}
