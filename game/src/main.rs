//! `cullet-game`: the sample game's command line (see the library for what it does).

fn main() -> std::process::ExitCode {
    cullet_game::main()
}
