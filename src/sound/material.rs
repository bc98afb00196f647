//! Per-band acoustic materials: how much energy a surface absorbs in each of the ten octave bands.

use crate::{Error, Result};

/// Number of frequency bands (thesis §6.1.5).
pub const BANDS: usize = 10;

/// Centre frequencies of the bands in Hz, as the thesis lists them.
pub const BAND_HZ: [f32; BANDS] = [
    20.0, 40.0, 80.0, 160.0, 320.0, 640.0, 1280.0, 2560.0, 5120.0, 10240.0,
];

/// A surface's energy absorption coefficient per band: a specular reflection keeps `1 - absorption[b]` of
/// the energy in band `b`. Use one material per kind of surface (wall, carpet, character); a triangle names
/// its material by index in [`SoundScene::new`](super::SoundScene::new).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AcousticMaterial {
    /// Fraction of the incident energy absorbed, per band, each in `[0, 1]`.
    pub absorption: [f32; BANDS],
}

impl AcousticMaterial {
    /// A material absorbing `absorption[b]` of the energy in band `b`; a coefficient outside `[0, 1]` (or
    /// not finite) is [`Error::InvalidOption`].
    pub fn new(absorption: [f32; BANDS]) -> Result<Self> {
        if let Some(b) = absorption.iter().position(|a| !(0.0..=1.0).contains(a)) {
            return Err(Error::InvalidOption(format!(
                "absorption of band {b} is {}, not in [0, 1]",
                absorption[b]
            )));
        }
        Ok(Self { absorption })
    }

    /// The same absorption in every band.
    pub fn uniform(absorption: f32) -> Result<Self> {
        Self::new([absorption; BANDS])
    }

    /// Energy kept per band by one reflection.
    pub(crate) fn reflectance(&self) -> [f32; BANDS] {
        self.absorption.map(|a| 1.0 - a)
    }
}
