//! `trimctl sim`: the device simulators as servers, until Ctrl-C: the galvo controller on TCP
//! (docs/protocols/galvo.md), the laser on a pseudo-terminal (its device node is printed), the
//! CNC speaking LinuxCNC's linuxcncrsh on TCP. They share one safety monitor; its violations are
//! reported on exit. Addresses go to stdout as one JSON object per line; diagnostics to stderr.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};

use anyhow::{Context, bail};
use trim_io::laser::Profile;
use trim_sim::cnc::{CncSim, CncSimConfig};
use trim_sim::fault::{Fault, FaultSwitch};
use trim_sim::galvo::{GalvoSim, GalvoSimConfig};
use trim_sim::laser::LaserSim;
use trim_sim::safety::SafetyMonitor;

/// The default galvo port (docs/protocols/galvo.md §1).
const DEFAULT_GALVO_PORT: u16 = 5020;
/// The default CNC port: linuxcncrsh's.
const DEFAULT_CNC_PORT: u16 = 5007;

/// Which simulators to start.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Which {
    /// The galvo controller.
    Galvo,
    /// The laser.
    Laser,
    /// The CNC.
    Cnc,
    /// All three.
    All,
}

/// Arguments of `trimctl sim`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Which simulators to start.
    #[arg(value_enum, default_value = "all")]
    which: Which,
    /// Address to listen on (loopback by default).
    #[arg(long, default_value_t = IpAddr::V4(Ipv4Addr::LOCALHOST))]
    bind: IpAddr,
    /// The galvo's TCP port (0: any free port).
    #[arg(long, default_value_t = DEFAULT_GALVO_PORT)]
    galvo_port: u16,
    /// The CNC's TCP port (0: any free port).
    #[arg(long, default_value_t = DEFAULT_CNC_PORT)]
    cnc_port: u16,
    /// The laser's profile: high-energy (the default, as job.toml's cell.laser_profile), monaco
    /// or ipg.
    #[arg(long, default_value = trim_io::laser::profile::DEFAULT_PROFILE)]
    profile: String,
    /// Galvo clock: real seconds per modelled second.
    #[arg(long, default_value_t = 1.0)]
    galvo_time_scale: f64,
    /// CNC motion: real seconds per simulated second.
    #[arg(long, default_value_t = 1.0)]
    cnc_time_scale: f64,
    /// Start the CNC out of E-stop, switched on and homed (else in E-stop and unhomed, as a
    /// real machine after power-up: `run` and `frame` then need --enable-machine and --home).
    #[arg(long)]
    cnc_ready: bool,
    /// A fault to inject, `DEVICE=KIND@COMMAND[#N]` or `galvo=KIND@marks:M[#LIST]`; KIND is
    /// drop-link, stall, garble or refuse. E.g. `galvo=stall@EXECUTE#2`,
    /// `laser=garble@emission_on`, `cnc=refuse@mdi#3`. Repeatable.
    #[arg(long = "fault", value_name = "DEVICE=FAULT")]
    faults: Vec<String>,
}

struct Faults {
    galvo: Vec<Fault>,
    laser: Vec<Fault>,
    cnc: Vec<Fault>,
}

fn parse_faults(specs: &[String]) -> anyhow::Result<Faults> {
    let mut f = Faults {
        galvo: Vec::new(),
        laser: Vec::new(),
        cnc: Vec::new(),
    };
    for spec in specs {
        let (device, fault) = spec
            .split_once('=')
            .with_context(|| format!("--fault {spec:?}: expected DEVICE=KIND@COMMAND[#N]"))?;
        let fault: Fault = fault
            .parse()
            .map_err(|e: String| anyhow::anyhow!("--fault {spec:?}: {e}"))?;
        match device {
            "galvo" => f.galvo.push(fault),
            "laser" => f.laser.push(fault),
            "cnc" => f.cnc.push(fault),
            other => bail!("--fault {spec:?}: unknown device {other:?} (galvo, laser or cnc)"),
        }
    }
    Ok(f)
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let faults = parse_faults(&args.faults)?;
    if !(args.galvo_time_scale >= 0.0 && args.cnc_time_scale >= 0.0) {
        bail!("time scales must be ≥ 0");
    }
    let rt = tokio::runtime::Runtime::new().context("tokio runtime")?;
    rt.block_on(serve(args, faults))
}

async fn serve(args: Args, faults: Faults) -> anyhow::Result<()> {
    // Installed before the simulators start: a stop signal from then on stops them cleanly.
    let mut signals = crate::stop_signal::StopSignals::install()?;
    let monitor = SafetyMonitor::new();
    let want = |w: Which| args.which == w || args.which == Which::All;
    let mut galvo = None;
    let mut laser = None;
    let mut cnc = None;
    if want(Which::Galvo) {
        let sim = GalvoSim::start(
            SocketAddr::new(args.bind, args.galvo_port),
            GalvoSimConfig {
                time_scale: args.galvo_time_scale,
                ..GalvoSimConfig::default()
            },
            monitor.clone(),
            FaultSwitch::new(faults.galvo),
        )
        .await
        .with_context(|| format!("galvo simulator on {}:{}", args.bind, args.galvo_port))?;
        println!("{}", serde_json::json!({"galvo": sim.addr().to_string()}));
        galvo = Some(sim);
    }
    if want(Which::Laser) {
        let profile = Profile::builtin(&args.profile)?;
        let sim = LaserSim::start(profile, monitor.clone(), FaultSwitch::new(faults.laser))
            .context("laser simulator")?;
        println!(
            "{}",
            serde_json::json!({"laser": sim.path().to_string_lossy(), "profile": args.profile})
        );
        laser = Some(sim);
    }
    if want(Which::Cnc) {
        let sim = CncSim::start(
            SocketAddr::new(args.bind, args.cnc_port),
            CncSimConfig {
                time_scale: args.cnc_time_scale,
                start_ready: args.cnc_ready,
                ..CncSimConfig::default()
            },
            monitor.clone(),
            FaultSwitch::new(faults.cnc),
        )
        .await
        .with_context(|| format!("CNC simulator on {}:{}", args.bind, args.cnc_port))?;
        println!("{}", serde_json::json!({"cnc": sim.addr().to_string()}));
        cnc = Some(sim);
    }
    eprintln!("trimctl sim: running; Ctrl-C (or SIGTERM, SIGHUP, SIGQUIT) stops");
    let name = signals.next().await;
    eprintln!("trimctl sim: {name}: stopping");
    if let Some(g) = &galvo {
        eprintln!(
            "galvo: {} vectors executed, {:.3} s modelled",
            g.marks().len(),
            g.elapsed_s()
        );
    }
    drop((galvo, laser, cnc));
    let violations = monitor.violations();
    for v in &violations {
        eprintln!("safety violation: {}", v.what);
    }
    if !violations.is_empty() {
        bail!("{} safety violations", violations.len());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_options_parse_per_device() {
        let f = parse_faults(&[
            "galvo=stall@EXECUTE#2".into(),
            "laser=garble@emission_on".into(),
            "cnc=refuse@mdi#3".into(),
        ])
        .unwrap();
        assert_eq!((f.galvo.len(), f.laser.len(), f.cnc.len()), (1, 1, 1));
        assert!(parse_faults(&["motor=stall@X".into()]).is_err());
        assert!(parse_faults(&["galvo=melt@X".into()]).is_err());
        assert!(parse_faults(&["galvo".into()]).is_err());
    }
}
