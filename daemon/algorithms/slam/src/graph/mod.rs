//! Graph SLAM (Karto / Cartographer class): scans matched against a local
//! submap, poses and relative-pose constraints in a pose graph, loop
//! closures verified by branch-and-bound correlative matching and a
//! sparse nonlinear least-squares optimiser with a robust kernel.
//!
//! - [`pose_graph`]: the SE(2) pose graph and its Levenberg–Marquardt optimiser.
//! - [`block_cholesky`]: the sparse factorisation it solves with, kept between solves.
//! - [`g2o`]: reading and writing 2D g2o files.
//! - [`slam`]: [`GraphSlam`], the back-end behind `SlamBackend`.

pub mod block_cholesky;
pub mod g2o;
pub mod pose_graph;
pub mod slam;

pub use pose_graph::{Edge, GraphError, OptimizeParams, OptimizeReport, PoseGraph, RobustKernel};
pub use slam::saved::{self, ResumedGraph, SavedGraphError};
pub use slam::{GraphParams, GraphSlam, GraphStats};
