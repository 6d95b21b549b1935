//! Laser command profiles as data (TOML, `crates/io/profiles/*.toml`, embedded in the binary):
//! what to send for each operation, what reply to expect, how to decode faults, and the
//! source's operating limits (`[limits]`, [`LaserLimits`]).

use std::collections::BTreeMap;

use serde::Deserialize;
use trim_cell::{Beam, CellError, LaserLimits};

/// The Coherent-Monaco-like profile's text.
pub const MONACO_TOML: &str = include_str!("../../profiles/monaco.toml");
/// The IPG-like profile's text.
pub const IPG_TOML: &str = include_str!("../../profiles/ipg.toml");
/// The high-energy picosecond profile's text (the paper's operating point is within it).
pub const HIGH_ENERGY_TOML: &str = include_str!("../../profiles/high-energy.toml");

/// The built-in profiles' names, the default (job.toml `cell.laser_profile`) first.
pub const BUILTIN: &[&str] = &[DEFAULT_PROFILE, "monaco", "ipg"];

/// The default laser profile: its limits allow the paper's operating point (53.59 W at
/// 250 kHz, 214.36 µJ), which is `Beam::default()`.
pub const DEFAULT_PROFILE: &str = "high-energy";

/// The placeholder for a value in a template.
pub const VALUE: &str = "{value}";

/// Operations a profile may define (keys of `[commands]`).
pub mod ops {
    /// Enable emission (required).
    pub const EMISSION_ON: &str = "emission_on";
    /// Disable emission (required).
    pub const EMISSION_OFF: &str = "emission_off";
    /// Set the power in percent.
    pub const SET_POWER_PCT: &str = "set_power_pct";
    /// Open the shutter.
    pub const SHUTTER_OPEN: &str = "shutter_open";
    /// Set the repetition rate in kHz.
    pub const SET_REP_RATE_KHZ: &str = "set_rep_rate_khz";
}

/// A laser command profile.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    /// Short name ("high-energy", "monaco", "ipg").
    pub name: String,
    /// One line for people.
    pub description: String,
    /// Baud rate (8N1).
    pub baud: u32,
    /// Line terminator, both directions.
    pub terminator: String,
    /// Replies that start with one of these are the device's refusal.
    pub error_prefixes: Vec<String>,
    /// The source's operating limits (`[limits]`): pulse energy, average power, repetition
    /// rate.
    pub limits: LaserLimits,
    /// Commands by operation.
    pub commands: BTreeMap<String, Exchange>,
    /// Queries by name.
    #[serde(default)]
    pub queries: BTreeMap<String, Query>,
    /// Fault code → text (for `fault-codes` queries).
    #[serde(default)]
    pub fault_codes: BTreeMap<String, String>,
    /// Status word bits (for `status-bits` queries).
    #[serde(default)]
    pub status_bits: Vec<StatusBit>,
}

/// One command: what to send, what to expect back.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Exchange {
    /// The line sent, `{value}` replaced by the argument.
    pub send: String,
    /// The expected reply, `{value}` matching the argument echoed.
    pub reply: String,
}

/// What a query answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum QueryKind {
    /// Comma-separated fault codes; "0" = none.
    FaultCodes,
    /// The key switch: 1 = on.
    Key,
    /// Emission: 1 = on.
    Emission,
    /// A status word (decimal) decoded with `status_bits`.
    StatusBits,
}

/// One query.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Query {
    /// The line sent.
    pub send: String,
    /// The reply template with `{value}`.
    pub reply: String,
    /// How to read the value.
    pub kind: QueryKind,
}

/// The meaning of a status bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BitMeaning {
    /// Set = a fault.
    Fault,
    /// Set = emission on.
    Emission,
    /// Set = the key switch is on.
    Key,
    /// Information only.
    Info,
}

/// One status bit.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StatusBit {
    /// Bit number (0 = least significant).
    pub bit: u32,
    /// Name.
    pub name: String,
    /// Meaning.
    pub meaning: BitMeaning,
}

/// A profile that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// Not valid TOML for a profile.
    #[error("laser profile: {0}")]
    Toml(#[from] toml::de::Error),
    /// A required part is missing or wrong.
    #[error("laser profile {name}: {what}")]
    Invalid {
        /// The profile name.
        name: String,
        /// What is wrong.
        what: String,
    },
    /// No built-in profile of that name.
    #[error("no built-in laser profile {name:?} (built in: {})", BUILTIN.join(", "), name = .0)]
    Unknown(String),
}

/// The decoded state of the laser from its queries.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Serialize)]
pub struct LaserStatus {
    /// Emission on, if a query tells.
    pub emission: Option<bool>,
    /// Key switch on, if a query tells.
    pub key_on: Option<bool>,
    /// Active faults, decoded to text.
    pub faults: Vec<String>,
}

impl Profile {
    /// Parses and checks a profile.
    pub fn from_toml(text: &str) -> Result<Profile, ProfileError> {
        let p: Profile = toml::from_str(text)?;
        let invalid = |what: String| ProfileError::Invalid {
            name: p.name.clone(),
            what,
        };
        for op in [ops::EMISSION_ON, ops::EMISSION_OFF] {
            if !p.commands.contains_key(op) {
                return Err(invalid(format!("[commands.{op}] is required")));
            }
        }
        p.limits
            .validate()
            .map_err(|e| invalid(format!("[limits]: {e}")))?;
        if p.terminator.is_empty() {
            return Err(invalid("the terminator is empty".into()));
        }
        if !p
            .queries
            .values()
            .any(|q| matches!(q.kind, QueryKind::FaultCodes | QueryKind::StatusBits))
        {
            return Err(invalid(
                "no query decodes faults (fault-codes or status-bits)".into(),
            ));
        }
        for (name, e) in &p.commands {
            if e.send.matches(VALUE).count() > 1 || e.reply.matches(VALUE).count() > 1 {
                return Err(invalid(format!("command {name}: more than one {VALUE}")));
            }
        }
        for (name, q) in &p.queries {
            if q.reply.matches(VALUE).count() != 1 {
                return Err(invalid(format!(
                    "query {name}: the reply needs one {VALUE}"
                )));
            }
        }
        Ok(p)
    }

    /// A built-in profile by name (one of [`BUILTIN`]).
    pub fn builtin(name: &str) -> Result<Profile, ProfileError> {
        match name {
            "high-energy" => Profile::from_toml(HIGH_ENERGY_TOML),
            "monaco" => Profile::from_toml(MONACO_TOML),
            "ipg" => Profile::from_toml(IPG_TOML),
            other => Err(ProfileError::Unknown(other.to_owned())),
        }
    }

    /// Refuses `beam`'s operating point when it is outside this source's [`LaserLimits`]
    /// ([`CellError::OutsideLaserLimits`], naming the profile and every limit broken).
    pub fn check_operating_point(&self, beam: &Beam) -> Result<(), CellError> {
        beam.check_limits(&self.limits, &self.name)
    }

    /// Whether a reply line is a refusal.
    #[must_use]
    pub fn is_error_reply(&self, line: &str) -> bool {
        self.error_prefixes
            .iter()
            .any(|p| line.starts_with(p.as_str()))
    }

    /// Decodes a query's value into the status.
    pub fn decode_query(
        &self,
        kind: QueryKind,
        value: &str,
        into: &mut LaserStatus,
    ) -> Result<(), String> {
        let value = value.trim();
        match kind {
            QueryKind::FaultCodes => {
                for code in value.split(',').map(str::trim) {
                    if code.is_empty()
                        || code
                            .parse::<u32>()
                            .map_err(|e| format!("fault code {code:?}: {e}"))?
                            == 0
                    {
                        continue;
                    }
                    let text = self
                        .fault_codes
                        .get(code)
                        .cloned()
                        .unwrap_or_else(|| "unknown fault".to_owned());
                    into.faults.push(format!("{code}: {text}"));
                }
            }
            QueryKind::Key => into.key_on = Some(parse_flag(value)?),
            QueryKind::Emission => into.emission = Some(parse_flag(value)?),
            QueryKind::StatusBits => {
                let word: u64 = value
                    .parse()
                    .map_err(|e| format!("status word {value:?}: {e}"))?;
                let mut emission = false;
                let mut key = None;
                for b in &self.status_bits {
                    let set = b.bit < 64 && word & (1 << b.bit) != 0;
                    match b.meaning {
                        BitMeaning::Fault if set => {
                            into.faults.push(format!("bit {}: {}", b.bit, b.name))
                        }
                        BitMeaning::Emission => emission |= set,
                        BitMeaning::Key => key = Some(set),
                        _ => {}
                    }
                }
                into.emission = Some(emission);
                if key.is_some() {
                    into.key_on = key;
                }
            }
        }
        Ok(())
    }
}

fn parse_flag(v: &str) -> Result<bool, String> {
    match v {
        "1" => Ok(true),
        "0" => Ok(false),
        other => Err(format!("expected 0 or 1, got {other:?}")),
    }
}

/// Fills a template's `{value}`.
#[must_use]
pub fn fill(template: &str, value: Option<&str>) -> String {
    match value {
        Some(v) => template.replace(VALUE, v),
        None => template.to_owned(),
    }
}

/// Matches a line against a template: `Some(captured value)` (empty when the template has no
/// `{value}`), `None` when it does not match.
#[must_use]
pub fn capture<'a>(template: &str, line: &'a str) -> Option<&'a str> {
    match template.split_once(VALUE) {
        None => (line == template).then_some(""),
        Some((pre, post)) => {
            let rest = line.strip_prefix(pre)?.strip_suffix(post)?;
            (!rest.is_empty()).then_some(rest)
        }
    }
}

/// Formats a numeric argument the way profiles send it (up to 3 decimals, no trailing zeros).
#[must_use]
pub fn format_value(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".to_owned()
    } else {
        s.to_owned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_builtin_profiles_load_with_their_line_settings() {
        let m = Profile::builtin("monaco").unwrap();
        assert_eq!((m.baud, m.terminator.as_str()), (19200, "\r\n"));
        assert_eq!(m.commands["emission_on"].send, "L=1");
        assert_eq!(m.queries["key"].send, "?K");
        let i = Profile::builtin("ipg").unwrap();
        assert_eq!((i.baud, i.terminator.as_str()), (57600, "\r"));
        assert_eq!(i.commands["emission_off"].send, "EMOFF");
        assert!(matches!(
            Profile::builtin("x"),
            Err(ProfileError::Unknown(_))
        ));
    }

    #[test]
    fn every_builtin_profile_states_its_limits_and_the_default_allows_the_papers_point() {
        for name in BUILTIN {
            let p = Profile::builtin(name).unwrap();
            assert_eq!(p.name, *name);
            p.limits.validate().unwrap();
        }
        // The paper's operating point (Beam::default: 53.59 W, 250 kHz, 214.36 µJ).
        let paper = Beam::default();
        Profile::builtin(DEFAULT_PROFILE)
            .unwrap()
            .check_operating_point(&paper)
            .unwrap();
        let e = Profile::builtin("monaco")
            .unwrap()
            .check_operating_point(&paper)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("\"monaco\"") && e.contains("limits.pulse_energy_uj_max = 40 µJ"),
            "{e}"
        );
        let e = Profile::builtin("ipg")
            .unwrap()
            .check_operating_point(&paper)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("limits.average_power_w_max = 30 W")
                && e.contains("limits.pulse_energy_uj_max = 100 µJ"),
            "{e}"
        );
    }

    #[test]
    fn profiles_without_usable_limits_are_refused_naming_the_key() {
        let without = MONACO_TOML.replace("[limits]", "[limitz]");
        assert!(Profile::from_toml(&without).is_err());
        let inverted =
            HIGH_ENERGY_TOML.replace("rep_rate_khz_min = 200.0", "rep_rate_khz_min = 5000.0");
        let e = Profile::from_toml(&inverted).unwrap_err().to_string();
        assert!(
            e.contains("high-energy") && e.contains("limits.rep_rate_khz_min"),
            "{e}"
        );
        let zero = IPG_TOML.replace("average_power_w_max = 30.0", "average_power_w_max = 0.0");
        let e = Profile::from_toml(&zero).unwrap_err().to_string();
        assert!(e.contains("limits.average_power_w_max"), "{e}");
    }

    #[test]
    fn profiles_missing_required_parts_are_refused() {
        let bad = MONACO_TOML.replace("[commands.emission_off]", "[commands.emission_offx]");
        let e = Profile::from_toml(&bad).unwrap_err();
        assert!(e.to_string().contains("emission_off"), "{e}");
        assert!(Profile::from_toml("name = 1").is_err());
    }

    #[test]
    fn templates_fill_and_capture() {
        assert_eq!(fill("PC={value}", Some("42.5")), "PC=42.5");
        assert_eq!(capture("SDC: {value}", "SDC: 42.5"), Some("42.5"));
        assert_eq!(capture("SDC: {value}", "SDC: "), None);
        assert_eq!(capture("EMON", "EMON"), Some(""));
        assert_eq!(capture("EMON", "EMOFF"), None);
        assert_eq!(format_value(42.50), "42.5");
        assert_eq!(format_value(80.0), "80");
        assert_eq!(format_value(0.0), "0");
    }

    #[test]
    fn faults_and_status_bits_decode() {
        let m = Profile::builtin("monaco").unwrap();
        let mut s = LaserStatus::default();
        m.decode_query(QueryKind::FaultCodes, "0", &mut s).unwrap();
        assert!(s.faults.is_empty());
        m.decode_query(QueryKind::FaultCodes, "3,99", &mut s)
            .unwrap();
        assert_eq!(
            s.faults,
            vec!["3: pump diode over temperature", "99: unknown fault"]
        );
        assert!(m.decode_query(QueryKind::FaultCodes, "x", &mut s).is_err());
        let i = Profile::builtin("ipg").unwrap();
        let mut s = LaserStatus::default();
        i.decode_query(
            QueryKind::StatusBits,
            &((1u64 << 2) | (1 << 3) | (1 << 19)).to_string(),
            &mut s,
        )
        .unwrap();
        assert_eq!(s.emission, Some(true));
        assert_eq!(s.key_on, Some(true));
        assert_eq!(s.faults, vec!["bit 3: high back reflection"]);
        assert!(i.is_error_reply("BCMD"));
        assert!(!i.is_error_reply("EMON"));
    }
}
