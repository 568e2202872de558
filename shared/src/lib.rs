//! The deltaz models shared by the host and the firmware (`no_std`, no allocator).
//!
//! One module per step of the paper ("Geometric accuracy of a structured light system"):
//!
//! | module | paper | what |
//! |---|---|---|
//! | [`rotation`] | eq. (2) | R = M_z(κ) M_y(φ) M_x(ω) |
//! | [`camera`] | section 6.2.1 | pixel ↔ photo coordinates, image refinement (principal point, distortion) |
//! | [`collinearity`] | eqs (1), (3), (4), (6), (7) | exterior orientation, projection, the camera ray |
//! | [`projector`] | eq. (5) | the calibrated projector: a centre and a table of rays |
//! | [`epipolar`] | eqs (1), (5) | a projector ray's image between two depths: a segment in the refined image |
//! | [`identify`] | section 4 (open problem) | which projector ray made each detected dot (epipolar segments) |
//! | [`intersection`] | eqs (8), (9) | λ, λp, and a least-squares closest approach |
//! | [`paper`] | Tables 1-4 | the paper's published figures |
//! | [`ray_table`] | eq. (5) | the device's packed rays: a model of the pattern and 24-bit slopes |
//! | [`rig`] | section 2 | camera + projector: an image point and a ray id → a 3D point |
//! | [`protocol`] | — | the host ↔ device wire protocol (messages, frames, calibration blob) |
//!
//! # Glossary and conventions
//! - Units: millimetres and radians everywhere.
//! - Rotation: R = M_z(κ) M_y(φ) M_x(ω) (eq. 2, as in the errata); R maps a world vector into the
//!   camera system: `x_cam = R (X − X0)`.
//! - Camera system: x right, y up, z backwards (the camera looks along −z); the image plane is at
//!   z = −f.
//! - Pixel coordinates (col, row): (0, 0) is the centre of the top-left pixel, row grows downwards.
//!   These are what files hold.
//! - Photo coordinates (mm, y up): x = (col − c0)·s, y = −(row − r0)·s with s the pixel size and
//!   (c0, r0) the pixel of the photo origin.
//! - Observed photo coordinates still carry the principal point offset and lens distortion;
//!   *refined* coordinates are those eq. (1) predicts ([`camera::InnerOrientation::refine`]).
//! - Generic over the scalar `T: RealField + Copy`: the host runs `f64`, the firmware `f32`.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![deny(missing_docs)]

pub mod camera;
pub mod collinearity;
pub mod epipolar;
pub mod identify;
pub mod intersection;
pub mod paper;
pub mod projector;
pub mod protocol;
pub mod ray_table;
pub mod rig;
pub mod rotation;

/// Everything that can go wrong in the shared models.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Error {
    /// The camera ray and the projector ray are (nearly) parallel: no intersection.
    DegenerateGeometry,
    /// Eq. (8)'s denominator n·u − w·l vanishes: the rays' projections on the XZ plane are parallel
    /// (for example a baseline along Y); use the closest approach instead.
    DegenerateXZ,
    /// The point lies behind the camera or on its principal plane (z ≥ 0 in the camera system).
    BehindCamera,
    /// The inverse of the image refinement did not converge (distortion too strong for the frame).
    RefinementDiverged,
    /// A parameter is NaN or infinite.
    NotFinite,
    /// The projector has no ray with this id.
    UnknownRay(u16),
    /// A projector ray's direction is NaN or not a unit vector.
    InvalidRay(u16),
    /// The projector's ray table is not sorted by strictly increasing id.
    UnsortedRays,
    /// A calibration with a non-positive focal length or pixel size, an empty sensor or no
    /// rays (see [`rig::Rig::validate`]).
    InvalidCalibration,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Error::DegenerateGeometry => "camera and projector rays are nearly parallel",
            Error::DegenerateXZ => {
                "eq. (8) is singular: the rays are parallel in the XZ plane (baseline along Y?)"
            }
            Error::BehindCamera => "the point lies behind the camera",
            Error::RefinementDiverged => "the inverse image refinement did not converge",
            Error::NotFinite => "a parameter is NaN or infinite",
            Error::UnknownRay(id) => return write!(f, "the projector has no ray {id}"),
            Error::InvalidRay(id) => {
                return write!(f, "projector ray {id} has a NaN or non-unit direction")
            }
            Error::UnsortedRays => "the projector's rays are not sorted by strictly increasing id",
            Error::InvalidCalibration => {
                "the calibration has a non-positive focal length or pixel size, an empty sensor or no rays"
            }
        })
    }
}

/// The shared crate's result type.
pub type Result<T> = core::result::Result<T, Error>;

/// √x in the generic scalar, as `x.sqrt()`, but with the FPU's `vsqrt.f32` for f32 on an
/// Arm hard-float target (the device): nalgebra's no_std `sqrt` is libm's software `sqrtf`
/// (about 80 instructions against VSQRT's 14 cycles). Both are correctly rounded, so the
/// device's results do not change. The f32 case is picked by `Any` at monomorphisation: no
/// branch remains in the code.
#[inline]
pub(crate) fn sqrt<T: nalgebra::RealField + Copy>(x: T) -> T {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        let mut out = x;
        if let Some(v) = (&mut out as &mut dyn core::any::Any).downcast_mut::<f32>() {
            *v = vsqrt(*v);
            return out;
        }
    }
    x.sqrt()
}

/// The FPU's square root (VSQRT.F32).
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
#[inline]
fn vsqrt(x: f32) -> f32 {
    let bits: u32;
    // SAFETY: the eabihf targets have a single-precision FPU, so VMOV and VSQRT.F32 exist; the
    // asm reads and writes only the named general registers and s0, which it declares
    // clobbered; no memory, no stack, no flags (VSQRT sets only FPSCR's cumulative exception
    // bits, which nothing here reads).
    unsafe {
        core::arch::asm!(
            "vmov s0, {x}",
            "vsqrt.f32 s0, s0",
            "vmov {r}, s0",
            x = in(reg) x.to_bits(),
            r = lateout(reg) bits,
            out("s0") _,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    f32::from_bits(bits)
}

/// A literal in the generic scalar (`f64` constants converted once, exactly for f64).
#[inline]
pub(crate) fn lit<T: nalgebra::RealField + Copy>(x: f64) -> T {
    nalgebra::convert(x)
}
