//! The untrimmed core the inspection's detection test scans (one view fixed to the machine,
//! tilted 25°; 500k points; burr webs 0.05–0.6 mm tall on 30 % of the contours, films over 15 %
//! of the openings), registered from where its scanner stood. Shared by the capture and
//! regional tests (`#[path]`-included).

use trim_register::regional::{RegisterSettings, Registration, register};
use trim_synth::{SynthCase, SynthParams, generate};

/// The parameters of the case of `seed`.
pub fn untrimmed_params(seed: u64) -> SynthParams {
    SynthParams {
        seed,
        scan_points: 500_000,
        dropouts: 0,
        burr_fraction: 0.3,
        burr_height_mm: [0.05, 0.6],
        burr_thickness_mm: [0.02, 0.1],
        blockage_fraction: 0.15,
        ..SynthParams::default()
    }
}

/// The case of `seed`.
#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a generator failure must fail the test"
)]
pub fn untrimmed_case(seed: u64) -> SynthCase {
    generate(&untrimmed_params(seed)).unwrap()
}

/// Its registration with the default settings, the scanner's position given, from the
/// fixture's nominal pose.
pub fn register_untrimmed(case: &SynthCase) -> Registration {
    register_untrimmed_with(case, |_| ())
}

/// [`register_untrimmed`] with the settings changed by `edit` first.
#[allow(
    dead_code,
    reason = "not every test file that includes this module uses it"
)]
#[expect(
    clippy::unwrap_used,
    reason = "a test helper: a refused registration must fail the test"
)]
pub fn register_untrimmed_with(
    case: &SynthCase,
    edit: impl FnOnce(&mut RegisterSettings),
) -> Registration {
    let mut settings = RegisterSettings {
        scanner_viewpoint_mm: Some(case.scanner_in_scan.coords.into()),
        ..RegisterSettings::default()
    };
    edit(&mut settings);
    register(
        &case.cad_points,
        &case.scan,
        &case.path,
        &case.scan_from_cad_nominal,
        &settings,
    )
    .unwrap()
}
