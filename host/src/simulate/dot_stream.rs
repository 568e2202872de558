//! Large dot-observation files for timing `reconstruct` and checking how it scales: the dots of
//! a scenario's true rig on surfaces at varying depth, and the *same* dots split over any
//! number of images (only the `image` column differs), so that a run over 20,000 images and one
//! over 2,000 do the same reconstruction work.

use super::images::true_rig;
use super::Scenario;
use crate::io::system_file::{SystemContent, SystemFrame, SystemRig};
use anyhow::{bail, Context, Result};
use deltaz_calib::projector_calibration::{
    CalibratedRay, LineCovariance, Model, ProjectorCalibration,
};
use deltaz_shared::collinearity::ExteriorOrientation;
use nalgebra::Vector3;
use std::io::Write;
use std::path::Path;

/// The scenario's true camera and projector as the content of a `system.json` in the camera
/// system (camera at the origin, unrotated): the paper's central model, its σ all zero.
pub fn true_system(scenario: &Scenario) -> Result<SystemContent> {
    let rig = true_rig(scenario);
    let projector = rig.projector_centred();
    let calibration = ProjectorCalibration {
        model: Model::Paper,
        centre: projector.centre(),
        centre_sigma: Vector3::zeros(),
        rays: projector
            .rays()
            .iter()
            .map(|r| CalibratedRay {
                id: r.id,
                direction: r.direction,
                offset: r.offset,
                planes: 0,
                miss_rms: 0.0,
                miss_max: 0.0,
                line_cov: LineCovariance([[0.0; 3]; 2]),
            })
            .collect(),
        single_plane: Vec::new(),
        left_out: Vec::new(),
    };
    let at_origin = ExteriorOrientation {
        kappa: 0.0,
        phi: 0.0,
        omega: 0.0,
        centre: Vector3::zeros(),
    };
    let mut content = SystemContent::new(
        *rig.grid(),
        *rig.inner(),
        ("truth", at_origin),
        &calibration,
    );
    content.frame = SystemFrame::Camera;
    Ok(content)
}

/// The ids of the rays whose dots stay on the sensor at every depth in `depths` (mm from the
/// camera centre along its axis): a ray's image is a straight line, so both ends suffice.
pub fn rays_on_sensor(rig: &SystemRig, depths: [f64; 2]) -> Vec<u16> {
    let grid = rig.grid();
    rig.projector_centred()
        .rays()
        .iter()
        .map(|r| r.id)
        .filter(|&id| {
            depths.iter().all(|&d| {
                rig.pixel_at_depth(id, d)
                    .is_ok_and(|(c, r)| grid.contains(c, r))
            })
        })
        .collect()
}

/// Writes `dots` observations `image,point,col,row` of `rig`, exact (no noise), over `images`
/// images of `dots / images` dots each (images `f1`, `f2`, ...). Dot j is ray `rays[j % group]`
/// on a surface at a depth in `depths` that changes every `group` dots, so any split of the
/// same `dots` into images of at most `group` dots gives the same dots: no ray twice in one
/// image. `group` must not exceed the number of rays, nor `dots / images` exceed `group`.
pub fn write_dots(
    path: &Path,
    rig: &SystemRig,
    rays: &[u16],
    (dots, images): (usize, usize),
    group: usize,
    depths: [f64; 2],
) -> Result<()> {
    let per_image = dots / images.max(1);
    if images == 0 || dots % images != 0 || per_image > group || group > rays.len() {
        bail!(
            "{dots} dots over {images} images in groups of {group} with {} rays: \
             the images must divide the dots, hold at most a group, and a group at most the rays",
            rays.len()
        );
    }
    let file = std::fs::File::create(path).with_context(|| format!("{}", path.display()))?;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let written = (|| -> Result<()> {
        writeln!(out, "image,point,col,row")?;
        // The golden ratio's fraction spreads the groups' depths evenly over the range.
        let golden = 0.618_033_988_749_895;
        let mut pixels = vec![(0.0, 0.0); group];
        for j in 0..dots {
            if j % group == 0 {
                let depth =
                    depths[0] + (depths[1] - depths[0]) * ((j / group) as f64 * golden).fract();
                for (pixel, &id) in pixels.iter_mut().zip(rays) {
                    *pixel = rig
                        .pixel_at_depth(id, depth)
                        .map_err(|e| anyhow::anyhow!("ray {id} at {depth} mm: {e}"))?;
                }
            }
            let (col, row) = pixels[j % group];
            writeln!(
                out,
                "f{},{},{col},{row}",
                j / per_image + 1,
                rays[j % group]
            )?;
        }
        out.flush()?;
        Ok(())
    })();
    written.with_context(|| format!("{}: cannot write", path.display()))
}
