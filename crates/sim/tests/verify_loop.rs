//! Verify and retrim on the twin, below the CLI (issue 23): a burred core is scanned and
//! registered; inspection of that first scan says which contours carry burrs and how tall; only
//! those are planned, with the passes their height needs, and run on the simulated cell; the
//! twin's part is trimmed by the landed cuts and rescanned; inspection of the rescan judges
//! every contour, and what failed is retrimmed. One layer of the first round is left out on
//! purpose: its contours must fail and the retrim must fix them.

#![expect(
    clippy::unwrap_used,
    reason = "integration test: a failed setup step should fail the test loudly"
)]

#[expect(
    dead_code,
    reason = "shared helpers; this test uses two of them (through twin_run)"
)]
#[path = "../../io/tests/common/mod.rs"]
mod common;
#[path = "support/twin_run.rs"]
mod twin_run;

use std::collections::BTreeSet;

use trim_cell::ProcessSettings;
use trim_cell::job::Job;
use trim_cell::truth::TruthSettings;
use trim_geom::{Path, Similarity3};
use trim_inspect::{InspectSettings, Inspection, Placement, Verdict, inspect};
use trim_plan::planner::{PlanSettings, plan};
use trim_plan::scan_field::LensSettings;
use trim_register::regional::{RegisterSettings, Registration, register};
use trim_sim::twin::{TrueCell, TruePart, Twin};
use trim_sim::twin_part::{ContourTrim, TwinPart};
use trim_synth::{SynthParams, generate};

use twin_run::run_on_twin;

/// The residual web and the gouge the product promises, µm.
const TOLERANCE_UM: f64 = 30.0;

/// The contours of `path` named in `ids`.
fn only(path: &Path, ids: &BTreeSet<i64>) -> Path {
    Path::new(
        path.contours()
            .iter()
            .filter(|c| ids.contains(&c.id()))
            .cloned()
            .collect(),
    )
    .unwrap()
}

/// Plans `ids` of the registered path, each polyline with the passes its measured excess
/// height needs (a web is no thicker than it is tall; the thickness is not seen from above).
fn plan_retrim(
    registered: &Path,
    ids: &BTreeSet<i64>,
    found: &Inspection,
    settings: &PlanSettings,
    process: &ProcessSettings,
) -> Job {
    let mut job = plan(&only(registered, ids), settings).unwrap();
    assert!(job.validation.passed, "{:?}", job.validation.violations);
    for z in &mut job.zones {
        for l in &mut z.layers {
            for p in &mut l.polylines {
                let c = found.contours.iter().find(|c| c.id == p.contour).unwrap();
                p.passes = process
                    .passes_through(c.excess_height_um * 1e-3)
                    .unwrap_or(trim_cell::process::MAX_PASSES);
            }
        }
    }
    job
}

/// Runs `job` on a simulated cell whose twin carries the true path, and returns the landed cuts.
async fn run(
    job: Job,
    settings: &PlanSettings,
    true_path: &Path,
) -> Vec<trim_sim::ablation::LandedCut> {
    let twin = Twin::new(
        TrueCell::new(&TruthSettings::default(), settings),
        TruePart::new(true_path),
    );
    run_on_twin(job, &twin).await;
    twin.cuts()
}

fn look(
    mesh: &trim_geom::mesh::Mesh,
    path: &Path,
    scan: &trim_geom::PointCloud,
    reg: &Registration,
) -> Inspection {
    inspect(
        mesh,
        path,
        scan.points(),
        &Placement::from_registration(reg),
        &InspectSettings::default(),
    )
    .unwrap()
}

fn failing(i: &Inspection) -> BTreeSet<i64> {
    i.contours
        .iter()
        .filter(|c| c.verdict == Verdict::Fail)
        .map(|c| c.id)
        .collect()
}

fn worst(state: &[ContourTrim]) -> (f64, f64) {
    state.iter().fold((0.0, 0.0), |(r, g), c| {
        (f64::max(r, c.residual_um), f64::max(g, c.gouge_um))
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn burrs_found_on_the_first_scan_are_trimmed_and_a_skipped_layer_is_caught_and_retrimmed() {
    let case = generate(&SynthParams {
        seed: 41,
        // A cell's scanner fixed to the machine, from three directions as the demo's: from one
        // view this seed's part slides 2.4 mm along itself and registration refuses it.
        scanner_views: 3,
        scan_points: 300_000,
        dropouts: 0,
        burr_fraction: 0.3,
        burr_height_mm: [0.05, 0.45],
        burr_thickness_mm: [0.02, 0.1],
        ..SynthParams::default()
    })
    .unwrap();
    let mesh = case.cad_mesh().unwrap();
    let reg = register(
        &case.cad_points,
        &case.scan,
        &case.path,
        &case.scan_from_cad_nominal,
        &RegisterSettings {
            scanner_viewpoint_mm: Some(case.scanner_in_scan.coords.into()),
            ..RegisterSettings::default()
        },
    )
    .unwrap();
    // The loop below is about inspection and retrim: it needs a part registration trusts.
    assert!(
        reg.report.global.refused.is_none(),
        "registration refused the part: {:?}",
        reg.report.global.refused
    );
    let settings = PlanSettings {
        field: LensSettings {
            telecentric: true,
            ..LensSettings::default()
        },
        ..PlanSettings::default()
    };
    let process = ProcessSettings::default();
    let kerf = process.kerf_width_mm(&settings.beam);
    let true_path = case.truth.clone();
    let burred: BTreeSet<i64> = case.burrs.iter().map(|b| b.contour).collect();
    let mut part = TwinPart::new(case.clone(), Similarity3::identity());

    // Detect: the first scan's inspection finds the burred contours.
    let first = look(&mesh, &case.path, &case.scan, &reg);
    let detected = failing(&first);
    assert!(!detected.is_empty());
    let missed: Vec<&i64> = burred.iter().filter(|id| !detected.contains(id)).collect();
    eprintln!(
        "detected {} of {} burred contours (missed {missed:?}); {} flagged clean",
        burred.len() - missed.len(),
        burred.len(),
        detected.difference(&burred).count()
    );
    assert!(
        missed.is_empty(),
        "burred contours not detected: {missed:?}"
    );

    // Round 1, one layer left out on purpose.
    let mut job = plan_retrim(&reg.path, &detected, &first, &settings, &process);
    let (zi, li) = job
        .zones
        .iter()
        .enumerate()
        .flat_map(|(zi, z)| (0..z.layers.len()).map(move |li| (zi, li)))
        .find(|&(zi, li)| !job.zones[zi].layers[li].polylines.is_empty())
        .unwrap();
    let skipped: BTreeSet<i64> = job.zones[zi].layers[li]
        .polylines
        .iter()
        .map(|p| p.contour)
        .collect();
    job.zones[zi].layers[li].polylines.clear();
    let after_one = part
        .trim(&run(job, &settings, &true_path).await, &process, kerf)
        .unwrap();
    let rescan = part.rescan(2).unwrap();
    let second = look(&mesh, &case.path, &rescan, &reg);
    let still = failing(&second);
    let (r1, g1) = worst(&after_one);
    eprintln!(
        "round 1 (layer zone {zi} layer {li} skipped, contours {skipped:?}): worst residual {r1:.1} µm, gouge {g1:.1} µm; failing {still:?}"
    );
    // The skipped layer's burred contours still carry their webs, and inspection says so.
    for id in skipped.intersection(&burred) {
        let truth = after_one.iter().find(|c| c.id == *id).unwrap();
        if truth.residual_um >= 50.0 {
            assert!(
                still.contains(id),
                "contour {id} left untrimmed but not failed"
            );
        }
    }

    // Round 2: what failed is retrimmed.
    if !still.is_empty() {
        let job = plan_retrim(&reg.path, &still, &second, &settings, &process);
        part.trim(&run(job, &settings, &true_path).await, &process, kerf)
            .unwrap();
    }
    let last = part.state();
    let third = look(&mesh, &case.path, &part.rescan(3).unwrap(), &reg);
    let (r2, g2) = worst(&last);
    eprintln!(
        "after the retrim: worst residual {r2:.1} µm, gouge {g2:.1} µm; failing {:?}",
        failing(&third)
    );
    assert!(failing(&third).is_empty(), "{:?}", failing(&third));
    assert!(r2 <= TOLERANCE_UM, "residual {r2}");
    assert!(g2 <= TOLERANCE_UM, "gouge {g2}");
}
