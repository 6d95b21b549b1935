//! `job.toml`: one serde schema for a whole job. Defaults live in code; `trimctl config --dump`
//! prints the full default file with comments ([`TEMPLATE`]); unknown keys and out-of-range
//! values are refused with the key named.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use trim_plan::{Beam, GalvoSettings};

/// The commented default job file. A test checks that it parses to [`JobConfig::default`] and
/// names every key.
pub const TEMPLATE: &str = include_str!("job.default.toml");

/// A whole job: part files, registration, beam, planning, galvo, cell and output.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JobConfig {
    /// The part's files.
    pub part: PartConfig,
    /// Beam optics (paper §2.1–2.2).
    pub beam: Beam,
    /// Galvo field, calibration, speeds and delays.
    pub galvo: GalvoSettings,
    /// Where the devices are.
    pub cell: CellConfig,
    /// Where the run folder goes.
    pub output: OutputConfig,
}

/// The part's input files. Relative paths are relative to the job file's folder. With no CAD,
/// path and scan, `trimctl run` uses the built-in demo part.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PartConfig {
    /// The CAD model: STL or PLY mesh, or a point cloud (PLY, PCD, XYZ).
    pub cad: Option<PathBuf>,
    /// The CAM template path (path CSV).
    pub path: Option<PathBuf>,
    /// The scan of the clamped part (PLY, PCD, XYZ).
    pub scan: Option<PathBuf>,
}

/// Device addresses. `"sim"` starts the built-in simulator for that device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CellConfig {
    /// The CNC (LinuxCNC linuxcncrsh) as HOST:PORT, or "sim".
    pub cnc: String,
    /// The galvo controller as HOST:PORT, or "sim".
    pub galvo: String,
    /// The laser's serial device (e.g. /dev/ttyUSB0), or "sim".
    pub laser: String,
    /// The laser command profile: "monaco" or "ipg".
    pub laser_profile: String,
}

impl Default for CellConfig {
    fn default() -> Self {
        CellConfig {
            cnc: SIM.into(),
            galvo: SIM.into(),
            laser: SIM.into(),
            laser_profile: "monaco".into(),
        }
    }
}

/// The word that selects a built-in simulator in [`CellConfig`].
pub const SIM: &str = "sim";

/// Where runs are recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// The folder under which each run gets a new time-stamped folder.
    pub runs_dir: PathBuf,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            runs_dir: PathBuf::from("runs"),
        }
    }
}

impl JobConfig {
    /// Reads and checks a job file. Relative part paths are resolved against its folder.
    pub fn load(path: &Path) -> anyhow::Result<JobConfig> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read job file {}", path.display()))?;
        let mut config = JobConfig::parse(&text)
            .with_context(|| format!("job file {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        for p in [
            &mut config.part.cad,
            &mut config.part.path,
            &mut config.part.scan,
        ]
        .into_iter()
        .flatten()
        {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        }
        Ok(config)
    }

    /// Parses job TOML and checks every value's range.
    pub fn parse(text: &str) -> anyhow::Result<JobConfig> {
        let config: JobConfig = toml::from_str(text).map_err(|e| {
            // One line: where, then toml's message (which names the key).
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            let message = e.message().trim().replace('\n', " ");
            match line {
                Some(l) => anyhow::anyhow!("line {l}: {message}"),
                None => anyhow::anyhow!("{message}"),
            }
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Checks every value's range, naming the key at fault.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.beam.validate().context("[beam]")?;
        validate_galvo(&self.galvo)?;
        for (key, value) in [
            ("cell.cnc", &self.cell.cnc),
            ("cell.galvo", &self.cell.galvo),
        ] {
            if value != SIM && value.parse::<std::net::SocketAddr>().is_err() {
                bail!("{key}: expected HOST:PORT (e.g. 127.0.0.1:5007) or \"sim\", got {value:?}");
            }
        }
        if self.cell.laser.is_empty() {
            bail!("cell.laser: expected a serial device path or \"sim\"");
        }
        if !["monaco", "ipg"].contains(&self.cell.laser_profile.as_str()) {
            bail!(
                "cell.laser_profile: expected \"monaco\" or \"ipg\", got {:?}",
                self.cell.laser_profile
            );
        }
        let parts = [&self.part.cad, &self.part.path, &self.part.scan];
        let given = parts.iter().filter(|p| p.is_some()).count();
        if given != 0 && given != 3 {
            bail!("part: give all of cad, path and scan, or none (for the built-in demo part)");
        }
        Ok(())
    }

    /// Whether the job runs the built-in demo part.
    pub fn is_demo(&self) -> bool {
        self.part.cad.is_none()
    }
}

fn validate_galvo(g: &GalvoSettings) -> anyhow::Result<()> {
    let positive = [
        ("galvo.field_mm[0]", g.field_mm[0]),
        ("galvo.field_mm[1]", g.field_mm[1]),
        ("galvo.bits_per_mm", g.bits_per_mm),
        ("galvo.mark_speed_mm_per_s", g.mark_speed_mm_per_s),
        ("galvo.jump_speed_mm_per_s", g.jump_speed_mm_per_s),
    ];
    for (key, v) in positive {
        if !(v.is_finite() && v > 0.0) {
            bail!("{key}: must be a finite number > 0, got {v}");
        }
    }
    let delays = [
        ("galvo.laser_on_delay_us", g.laser_on_delay_us),
        ("galvo.laser_off_delay_us", g.laser_off_delay_us),
        ("galvo.jump_delay_us", g.jump_delay_us),
        ("galvo.mark_delay_us", g.mark_delay_us),
        ("galvo.polygon_delay_us", g.polygon_delay_us),
    ];
    for (key, v) in delays {
        if !(v.is_finite() && (0.0..=1e6).contains(&v)) {
            bail!("{key}: must be between 0 and 1e6 µs, got {v}");
        }
    }
    // The field in bits must fit the protocol's signed 32-bit coordinates.
    let half_bits = 0.5 * g.field_mm[0].max(g.field_mm[1]) * g.bits_per_mm;
    if half_bits > f64::from(i32::MAX) {
        bail!("galvo.bits_per_mm: field × calibration exceeds the 32-bit coordinate range");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn template_is_the_default_and_names_every_key() {
        let parsed = JobConfig::parse(TEMPLATE).expect("template parses");
        assert_eq!(parsed, JobConfig::default());
        let value = toml::Value::try_from(JobConfig::default()).unwrap();
        let table = value.as_table().unwrap();
        for (section, body) in table {
            assert!(TEMPLATE.contains(&format!("[{section}]")), "[{section}] missing");
            if let Some(t) = body.as_table() {
                for key in t.keys() {
                    assert!(
                        TEMPLATE.contains(&format!("\n{key} =")) || TEMPLATE.contains(&format!("\n# {key} =")),
                        "{section}.{key} missing from the template"
                    );
                }
            }
        }
    }

    #[test]
    fn unknown_keys_are_refused_with_the_key_named() {
        let e = JobConfig::parse("[beam]\npowr_w = 10\n").unwrap_err().to_string();
        assert!(e.contains("powr_w"), "{e}");
        let e = JobConfig::parse("[bem]\n").unwrap_err().to_string();
        assert!(e.contains("bem"), "{e}");
    }

    #[test]
    fn out_of_range_values_are_refused_with_the_key_named() {
        for (text, key) in [
            ("[galvo]\nmark_speed_mm_per_s = -5\n", "galvo.mark_speed_mm_per_s"),
            ("[galvo]\njump_delay_us = nan\n", "galvo.jump_delay_us"),
            ("[cell]\ncnc = \"localhost\"\n", "cell.cnc"),
            ("[cell]\nlaser_profile = \"acme\"\n", "cell.laser_profile"),
            ("[part]\ncad = \"a.stl\"\n", "part"),
        ] {
            let e = format!("{:#}", JobConfig::parse(text).unwrap_err());
            assert!(e.contains(key), "{text}: {e}");
        }
        let e = format!("{:#}", JobConfig::parse("[beam]\npower_w = -1\n").unwrap_err());
        assert!(e.contains("power_w"), "{e}");
    }
}
