//! What each emulated model says about itself.
//!
//! URG-04LX strings are the real ones from a firmware 3.1.00 device (the
//! hokuyo codec's `tests/vectors/A_wiki_vv_pp_ii.txt`; its PP geometry is the
//! codec's [`Geometry::URG_04LX`]). The UTM-30LX-EW PP is the real one
//! (`I_utm30lxew_pp.txt` there); its VV and II were not captured and are
//! plausible stand-ins, marked below.

use smokenav_hokuyo_codec::Geometry;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Model {
    Urg04lx,
    Utm30lxEw,
}

/// Everything model-specific the device needs.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSpec {
    pub model: Model,
    pub vv: [(&'static str, &'static str); 5],
    pub modl: &'static str,
    pub geometry: Geometry,
    /// Boots in SCIP 1.1 (the 04LX reverts to it at every power cycle).
    pub boots_scip11: bool,
    /// ME is a valid command.
    pub supports_me: bool,
    /// Bit rates SS accepts over RS-232.
    pub bauds: &'static [u32],
    /// RS-232 rate after power-up / RS.
    pub default_baud: u32,
}

impl Model {
    pub fn spec(self) -> ModelSpec {
        match self {
            Model::Urg04lx => ModelSpec {
                model: self,
                vv: [
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", "SOKUIKI Sensor URG-04LX"),
                    ("FIRM", "3.1.00(18/Jan./2007)"),
                    ("PROT", "SCIP 2.0"),
                    ("SERI", "H0614967"),
                ],
                modl: "URG-04LX(Hokuyo Automatic Co.,Ltd.)",
                geometry: Geometry::URG_04LX,
                boots_scip11: true,
                supports_me: false,
                bauds: &[19_200, 57_600, 115_200],
                default_baud: 19_200,
            },
            Model::Utm30lxEw => ModelSpec {
                model: self,
                // Not captured: stand-in VV in the shape of the 04LX's.
                vv: [
                    ("VEND", "Hokuyo Automatic Co.,Ltd."),
                    ("PROD", "SOKUIKI Sensor TOP-URG UTM-30LX-EW"),
                    ("FIRM", "1.1.0(emulated)"),
                    ("PROT", "SCIP 2.0"),
                    ("SERI", "H0000000"),
                ],
                modl: "UTM-30LX-EW",
                geometry: Geometry {
                    dmin_mm: 23,
                    dmax_mm: 60_000,
                    ares: 1440,
                    amin: 0,
                    amax: 1080,
                    afrt: 540,
                    scan_rpm: 2400,
                },
                boots_scip11: false,
                supports_me: true,
                bauds: &[],
                default_baud: 0,
            },
        }
    }
}
