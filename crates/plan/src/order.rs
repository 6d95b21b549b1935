//! Zone ordering: nearest neighbour, then 2-opt, on an open path from the start pose
//! (DESIGN.md "Machine pose"; issue 3: "keep machine travel short").
//!
//! Costs may be asymmetric (leaving a zone from its last layer, entering the next at its first):
//! a reversal also reverses every edge inside the reversed stretch, which 2-opt accounts for
//! with prefix sums. The cost matrix takes n² evaluations: above [`TWO_OPT_MAX_ZONES`] zones only
//! the nearest-neighbour order is used.

/// The most zones 2-opt is run on.
pub const TWO_OPT_MAX_ZONES: usize = 400;

/// The most 2-opt passes (each pass tries every reversal once).
pub const TWO_OPT_MAX_PASSES: usize = 50;

/// An improvement must be larger than this (seconds) to count.
const IMPROVEMENT_EPS: f64 = 1e-12;

/// The cost of visiting `order` from the start: `start(first) + Σ cost(a, b)`.
pub fn path_cost(
    order: &[usize],
    start: &impl Fn(usize) -> f64,
    cost: &impl Fn(usize, usize) -> f64,
) -> f64 {
    match order.first() {
        None => 0.0,
        Some(&first) => start(first) + order.windows(2).map(|w| cost(w[0], w[1])).sum::<f64>(),
    }
}

/// An order of `n` items: nearest neighbour from the start (ties: the lower index), then 2-opt
/// with O(1) move evaluation (prefix sums of the forward and backward edge costs along the
/// current order, so reversing a stretch costs its backward sum instead of its forward sum).
pub fn order(
    n: usize,
    start: impl Fn(usize) -> f64,
    cost: impl Fn(usize, usize) -> f64,
) -> Vec<usize> {
    let matrix: Vec<f64> = (0..n * n).map(|k| cost(k / n, k % n)).collect();
    let c = |i: usize, j: usize| matrix[i * n + j];
    let starts: Vec<f64> = (0..n).map(&start).collect();
    let mut left: Vec<usize> = (0..n).collect();
    let mut out = Vec::with_capacity(n);
    let mut current: Option<usize> = None;
    while !left.is_empty() {
        let (pos, _) = left
            .iter()
            .enumerate()
            .fold((0, f64::INFINITY), |best, (pos, &j)| {
                let v = current.map_or(starts[j], |i| c(i, j));
                if v < best.1 { (pos, v) } else { best }
            });
        let next = left.remove(pos);
        out.push(next);
        current = Some(next);
    }
    if !(3..=TWO_OPT_MAX_ZONES).contains(&n) {
        return out;
    }
    for _ in 0..TWO_OPT_MAX_PASSES {
        let mut improved = false;
        for i in 0..n - 1 {
            // Prefix sums of the edge costs along the current order, forward and backward.
            let mut fwd = vec![0.0; n];
            let mut bwd = vec![0.0; n];
            for t in 1..n {
                fwd[t] = fwd[t - 1] + c(out[t - 1], out[t]);
                bwd[t] = bwd[t - 1] + c(out[t], out[t - 1]);
            }
            let mut best: Option<(usize, f64)> = None;
            for j in i + 1..n {
                let before = if i == 0 {
                    starts[out[0]]
                } else {
                    c(out[i - 1], out[i])
                };
                let after_old = if j + 1 < n {
                    c(out[j], out[j + 1])
                } else {
                    0.0
                };
                let enter = if i == 0 {
                    starts[out[j]]
                } else {
                    c(out[i - 1], out[j])
                };
                let leave = if j + 1 < n {
                    c(out[i], out[j + 1])
                } else {
                    0.0
                };
                let delta =
                    (enter + leave + (bwd[j] - bwd[i])) - (before + after_old + (fwd[j] - fwd[i]));
                if delta < -IMPROVEMENT_EPS && best.is_none_or(|(_, d)| delta < d) {
                    best = Some((j, delta));
                }
            }
            if let Some((j, _)) = best {
                out[i..=j].reverse();
                improved = true;
            }
        }
        if !improved {
            break;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_opt_untangles_a_crossing_tour() {
        // Points on a line visited from x = 0; nearest neighbour already gives the sorted
        // order for points on a line, so use a layout where it does not: a zig-zag.
        let xs: [f64; 6] = [0.0, 10.0, 1.0, 11.0, 2.0, 12.0];
        let ys: [f64; 6] = [0.0, 0.0, 5.0, 5.0, 10.0, 10.0];
        let d = |i: usize, j: usize| (xs[i] - xs[j]).hypot(ys[i] - ys[j]);
        let start = |j: usize| xs[j].hypot(ys[j]);
        let o = order(6, start, d);
        let mut sorted = o.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..6).collect::<Vec<_>>());
        // Brute force the optimum over all 720 permutations.
        let mut perm: Vec<usize> = (0..6).collect();
        let mut best = f64::INFINITY;
        permute(&mut perm, 0, &mut |p| {
            best = best.min(path_cost(p, &start, &d))
        });
        let got = path_cost(&o, &start, &d);
        assert!(got <= best * 1.10 + 1e-9, "2-opt {got} vs optimum {best}");
    }

    fn permute(p: &mut Vec<usize>, k: usize, f: &mut impl FnMut(&[usize])) {
        if k == p.len() {
            f(p);
            return;
        }
        for i in k..p.len() {
            p.swap(k, i);
            permute(p, k + 1, f);
            p.swap(k, i);
        }
    }
}
