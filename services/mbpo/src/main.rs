//! `mbpo`: the command-line entry point; the command is the `mbpo` library's (its `main`),
//! so a program of one's own with a registered algorithm is the same command.

fn main() -> std::process::ExitCode {
    mbpo::main()
}
