//! `cullet-game`: the sample game's command line (see the library for what it does).

#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    cullet_game::main()
}
