//! The `trimctl` command line.

fn main() -> std::process::ExitCode {
    eprintln!("trimctl: not built yet (see README)");
    std::process::ExitCode::FAILURE
}
