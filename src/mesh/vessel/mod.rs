//! The vessel pipeline: a lumen surface (a file, or the built-in implicit
//! arch tree) turned into a tetrahedral wall with node sets and segment
//! labels.
//!
//! ```text
//! lumen surface -> clean + find openings (boundary loops, or planar caps)
//!   -> isotropic remesh to the target edge length
//!   -> offset outward by the wall thickness, L layers of prisms
//!   -> prisms split into conforming, positively oriented tets
//!   -> node sets (openings, inner_wall, outer_wall) + segment labels
//! ```

pub mod branched;
pub mod caps;
pub mod centreline;
pub mod error;
pub mod implicit;
pub mod pipeline;
pub mod remesh;
pub mod wall;

pub use error::VesselError;
