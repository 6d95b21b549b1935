//! Hatch tracks in a path: they take negative contour ids, so they never collide with a CAM
//! path's. Region `r`, track `t` (0-based) is `−(1 + r·TRACKS_PER_REGION + t)`. The ids stay
//! internal: what an operator reads (zone table, report, SVG) names them `hatch[r] tracks a–b`,
//! tracks counted from 1 ([`describe_contours`]).

use trim_geom::ContourId;

/// How many track ids each hatch region owns.
pub const TRACKS_PER_REGION: i64 = 100_000;

/// The contour id of track `track` of region `region` (both 0-based).
#[must_use]
pub fn track_id(region: usize, track: usize) -> ContourId {
    -(1 + region as i64 * TRACKS_PER_REGION + track as i64)
}

/// The (region, track) a contour id stands for (both 0-based), or `None` for a CAM contour.
#[must_use]
pub fn track_of(id: ContourId) -> Option<(usize, usize)> {
    (id < 0).then(|| {
        let n = -(id + 1);
        (
            (n / TRACKS_PER_REGION) as usize,
            (n % TRACKS_PER_REGION) as usize,
        )
    })
}

/// A list of contour ids as an operator reads it: the CAM contours as `[2, 41, 42, 50]`, then
/// each hatch region's tracks as `hatch[0] tracks 1–70` (counted from 1, runs joined by "–").
#[must_use]
pub fn describe_contours(ids: &[ContourId]) -> String {
    let mut cam: Vec<ContourId> = ids.iter().copied().filter(|&id| id >= 0).collect();
    cam.sort_unstable();
    let mut tracks: Vec<(usize, usize)> = ids.iter().filter_map(|&id| track_of(id)).collect();
    tracks.sort_unstable();
    tracks.dedup();
    let mut parts = Vec::new();
    if !cam.is_empty() || tracks.is_empty() {
        parts.push(format!("{cam:?}"));
    }
    let mut rest = tracks.as_slice();
    while let Some(&(region, _)) = rest.first() {
        let n = rest.iter().take_while(|(r, _)| *r == region).count();
        let numbers: Vec<usize> = rest[..n].iter().map(|(_, t)| t + 1).collect();
        let word = if n == 1 { "track" } else { "tracks" };
        parts.push(format!("hatch[{region}] {word} {}", runs(&numbers)));
        rest = &rest[n..];
    }
    parts.join(" ")
}

/// Sorted numbers as runs: `1–5, 8, 10–12`.
fn runs(numbers: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < numbers.len() {
        let mut j = i;
        while j + 1 < numbers.len() && numbers[j + 1] == numbers[j] + 1 {
            j += 1;
        }
        out.push(if j == i {
            numbers[i].to_string()
        } else {
            format!("{}–{}", numbers[i], numbers[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn track_ids_round_trip_and_read_as_regions_and_tracks() {
        for (region, track) in [(0, 0), (0, 69), (3, 12), (1, 99_999)] {
            assert_eq!(track_of(track_id(region, track)), Some((region, track)));
        }
        assert_eq!(track_of(0), None);
        assert_eq!(track_of(42), None);
        assert_eq!(track_id(0, 0), -1);
        let mut ids: Vec<ContourId> = (0..70).map(|t| track_id(0, t)).collect();
        ids.extend([2, 41, 42, 50]);
        assert_eq!(
            describe_contours(&ids),
            "[2, 41, 42, 50] hatch[0] tracks 1–70"
        );
        let ids = [
            track_id(1, 7),
            track_id(0, 0),
            track_id(0, 1),
            track_id(0, 2),
            track_id(0, 5),
            track_id(0, 9),
            track_id(0, 10),
        ];
        assert_eq!(
            describe_contours(&ids),
            "hatch[0] tracks 1–3, 6, 10–11 hatch[1] track 8"
        );
        assert_eq!(describe_contours(&[7, 3]), "[3, 7]");
        assert_eq!(describe_contours(&[]), "[]");
    }
}
