//! A layer's polylines (galvo millimetres) as a galvo list (bits), from any vector on.
//!
//! A **vector** is one segment of a polyline in one of its passes; a layer's vectors are
//! numbered from 0 over its polylines in order, a polyline's passes one after the other (a
//! polyline of 3 segments marked twice is 6 vectors). A list that starts at vector k jumps to the start of vector k and marks
//! from there, so a resumed layer never marks a vector twice.

use trim_cell::job::{GalvoSettings, Layer};

use super::protocol::ListCommand;

/// A point in galvo millimetres that does not fit the field or the bit range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("polyline {polyline} point {point} at ({x_mm}, {y_mm}) mm is outside the galvo field")]
pub struct OutOfField {
    /// Polyline index in the layer.
    pub polyline: usize,
    /// Point index in the polyline.
    pub point: usize,
    /// x (mm).
    pub x_mm: f64,
    /// y (mm).
    pub y_mm: f64,
}

/// Millimetres to bits: `round(mm · bits_per_mm)`; `None` outside the field or the i32 range.
#[must_use]
pub fn mm_to_bits(xy_mm: [f64; 2], settings: &GalvoSettings) -> Option<[i32; 2]> {
    let half = [settings.field_mm[0] / 2.0, settings.field_mm[1] / 2.0];
    let mut out = [0_i32; 2];
    for i in 0..2 {
        if !xy_mm[i].is_finite() || xy_mm[i].abs() > half[i] + 1e-9 {
            return None;
        }
        let b = (xy_mm[i] * settings.bits_per_mm).round();
        if b < f64::from(i32::MIN) || b > f64::from(i32::MAX) {
            return None;
        }
        out[i] = b as i32;
    }
    Some(out)
}

/// One vector in bits: `(from, to)`.
pub type VectorBits = ([i32; 2], [i32; 2]);

/// The number of vectors of a layer.
#[must_use]
pub fn vector_count(layer: &Layer) -> u32 {
    let n: usize = layer
        .polylines
        .iter()
        .map(|p| p.galvo_commands().len().saturating_sub(1) * p.passes as usize)
        .sum();
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// The index of the polyline that vector `vector` of a layer belongs to (whichever of its
/// passes); `None` past the layer's last vector.
#[must_use]
pub fn polyline_of_vector(layer: &Layer, vector: u64) -> Option<usize> {
    let mut v = vector;
    for (i, p) in layer.polylines.iter().enumerate() {
        let n = (p.galvo_commands().len().saturating_sub(1) * p.passes as usize) as u64;
        if v < n {
            return Some(i);
        }
        v -= n;
    }
    None
}

/// The layer's vectors in bits, `(from, to)`, in order.
pub fn vectors_bits(
    layer: &Layer,
    settings: &GalvoSettings,
) -> Result<Vec<VectorBits>, OutOfField> {
    let mut out = Vec::new();
    for (pi, pl) in layer.polylines.iter().enumerate() {
        let pts = bits_of(pi, pl.galvo_commands(), settings)?;
        for _ in 0..pl.passes {
            out.extend(pts.windows(2).map(|w| (w[0], w[1])));
        }
    }
    Ok(out)
}

fn bits_of(
    pi: usize,
    pts: &[[f64; 2]],
    settings: &GalvoSettings,
) -> Result<Vec<[i32; 2]>, OutOfField> {
    pts.iter()
        .enumerate()
        .map(|(i, p)| {
            mm_to_bits(*p, settings).ok_or(OutOfField {
                polyline: pi,
                point: i,
                x_mm: p[0],
                y_mm: p[1],
            })
        })
        .collect()
}

/// The list commands for a layer from vector `first_vector` on: speeds and delays, then per
/// polyline and pass a jump to its (first remaining) start and marks along it.
pub fn layer_list(
    layer: &Layer,
    settings: &GalvoSettings,
    first_vector: u32,
) -> Result<Vec<ListCommand>, OutOfField> {
    let bits_per_ms = settings.bits_per_mm / 1000.0;
    let ns = |us: f64| (us * 1000.0).round().clamp(0.0, f64::from(u32::MAX)) as u32;
    let mut out = vec![
        ListCommand::Speeds {
            jump_bits_per_ms: settings.jump_speed_mm_per_s * bits_per_ms,
            mark_bits_per_ms: settings.mark_speed_mm_per_s * bits_per_ms,
        },
        ListCommand::LaserDelays {
            on_ns: ns(settings.laser_on_delay_us),
            off_ns: ns(settings.laser_off_delay_us),
        },
        ListCommand::ScannerDelays {
            jump_ns: ns(settings.jump_delay_us),
            mark_ns: ns(settings.mark_delay_us),
            polygon_ns: ns(settings.polygon_delay_us),
        },
    ];
    let mut index = 0_u32;
    for (pi, pl) in layer.polylines.iter().enumerate() {
        let pts = bits_of(pi, pl.galvo_commands(), settings)?;
        for _ in 0..pl.passes {
            let mut jumped = false;
            for w in pts.windows(2) {
                if index >= first_vector {
                    if !jumped {
                        out.push(ListCommand::Jump {
                            x: w[0][0],
                            y: w[0][1],
                        });
                        jumped = true;
                    }
                    out.push(ListCommand::Mark {
                        x: w[1][0],
                        y: w[1][1],
                    });
                }
                index += 1;
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use trim_cell::job::{Polyline, Pose};

    use super::*;

    fn layer() -> Layer {
        Layer {
            index: 0,
            focus_point: [0.0; 3],
            pose: Pose::default(),
            polylines: vec![
                Polyline::from_points(1, vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]),
                Polyline::from_points(2, vec![[-2.0, -2.0], [-2.0, -3.0]]),
            ],
        }
    }

    #[test]
    fn resumed_lists_jump_to_the_first_unmarked_vector() {
        let s = GalvoSettings::default();
        let l = layer();
        assert_eq!(vector_count(&l), 3);
        let full = layer_list(&l, &s, 0).unwrap();
        let marks = |cmds: &[ListCommand]| {
            cmds.iter()
                .filter(|c| matches!(c, ListCommand::Mark { .. }))
                .count()
        };
        assert_eq!(marks(&full), 3);
        assert_eq!(full[3], ListCommand::Jump { x: 0, y: 0 });
        let from1 = layer_list(&l, &s, 1).unwrap();
        assert_eq!(marks(&from1), 2);
        assert_eq!(from1[3], ListCommand::Jump { x: 10_000, y: 0 });
        assert_eq!(
            from1[4],
            ListCommand::Mark {
                x: 10_000,
                y: 10_000
            }
        );
        let from2 = layer_list(&l, &s, 2).unwrap();
        assert_eq!(
            from2[3..],
            [
                ListCommand::Jump {
                    x: -20_000,
                    y: -20_000
                },
                ListCommand::Mark {
                    x: -20_000,
                    y: -30_000
                }
            ]
        );
        assert_eq!(marks(&layer_list(&l, &s, 3).unwrap()), 0);
        assert_eq!(
            vectors_bits(&l, &s).unwrap()[2],
            ([-20_000, -20_000], [-20_000, -30_000])
        );
    }

    #[test]
    fn a_polyline_of_several_passes_is_marked_that_many_times_and_resumes_within_a_pass() {
        let s = GalvoSettings::default();
        let mut l = layer();
        l.polylines[0].passes = 3;
        // 2 vectors × 3 passes, then 1.
        assert_eq!(vector_count(&l), 7);
        let jumps_and_marks = |cmds: &[ListCommand]| {
            cmds.iter()
                .filter(|c| matches!(c, ListCommand::Jump { .. } | ListCommand::Mark { .. }))
                .copied()
                .collect::<Vec<_>>()
        };
        let pass = [
            ListCommand::Jump { x: 0, y: 0 },
            ListCommand::Mark { x: 10_000, y: 0 },
            ListCommand::Mark {
                x: 10_000,
                y: 10_000,
            },
        ];
        let full = jumps_and_marks(&layer_list(&l, &s, 0).unwrap());
        assert_eq!(full[..3], pass);
        assert_eq!(full[3..6], pass);
        assert_eq!(full[6..9], pass);
        assert_eq!(full.len(), 11);
        // Stopped after the second pass's first vector: the rest of that pass, the third pass
        // and the next polyline; nothing marked twice.
        let resumed = jumps_and_marks(&layer_list(&l, &s, 3).unwrap());
        assert_eq!(
            resumed[..2],
            [
                ListCommand::Jump { x: 10_000, y: 0 },
                ListCommand::Mark {
                    x: 10_000,
                    y: 10_000
                }
            ]
        );
        assert_eq!(resumed[2..5], pass);
        assert_eq!(resumed.len(), 7);
        assert_eq!(vectors_bits(&l, &s).unwrap().len(), 7);
        assert_eq!(
            (0..8)
                .map(|v| polyline_of_vector(&l, v))
                .collect::<Vec<_>>(),
            [0, 0, 0, 0, 0, 0, 1]
                .map(Some)
                .into_iter()
                .chain([None])
                .collect::<Vec<_>>()
        );
        // The time model counts every pass.
        let once = trim_cell::ListComposition::of(&layer().polylines);
        let thrice = trim_cell::ListComposition::of(&l.polylines);
        assert_eq!(thrice.vectors, once.vectors + 4);
        assert_eq!(thrice.jumps, once.jumps + 2);
        assert!((thrice.mark_mm - (once.mark_mm + 4.0)).abs() < 1e-12);
    }

    #[test]
    fn points_outside_the_field_are_named() {
        let s = GalvoSettings::default();
        let mut l = layer();
        l.polylines[1].points[1] = [0.0, 50.5];
        l.polylines[1].commands[1] = [0.0, 50.5];
        let e = layer_list(&l, &s, 0).unwrap_err();
        assert_eq!((e.polyline, e.point), (1, 1));
        assert_eq!(mm_to_bits([50.0, -50.0], &s), Some([500_000, -500_000]));
        assert_eq!(mm_to_bits([f64::NAN, 0.0], &s), None);
    }
}
