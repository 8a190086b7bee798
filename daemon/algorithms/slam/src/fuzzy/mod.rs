//! Fuzzy confidence maps and SLAM by registering them (Hou et al. 2014, with
//! a Hokuyo URG-04LX).
//!
//! - [`confidence`]: the confidence functions of a reading (eqs. 1–4) and
//!   the combination rule (eq. 7), per beam kind.
//! - [`map`]: local and global fuzzy maps `Mo` / `Ms`, polar readings
//!   painted into Cartesian cells by fuzzy union (eqs. 5–6).
//! - [`registration`]: motion-predicted cropping (eqs. 8–9), the overlap
//!   cost, Cuckoo search and a correlative search on it.
//! - [`slam`]: [`FuzzySlam`], the back-end behind `SlamBackend`.

pub mod confidence;
pub mod map;
pub mod registration;
pub mod slam;

pub use confidence::ConfidenceModel;
pub use map::{FuzzyBeam, FuzzyGrid, fuzzy_beams};
pub use slam::{FuzzySlam, FuzzyStats};
