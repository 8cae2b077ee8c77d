//! The command line's subcommands (binary only: nothing here is part of the
//! library). Each file turns parsed arguments into calls on the library and
//! prints what they return; the work itself lives in the library modules.

pub mod cubic;
pub mod mesh;
pub mod progress;
pub mod reduced;
pub mod run;
pub mod sim;
pub mod stream;
pub mod wire;
