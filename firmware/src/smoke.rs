//! The boot-time smoke computation: one intersection on the paper's rig (Tables 1-4), so a board
//! shows at once that the shared model runs on it.

use deltaz_shared::collinearity::Camera;
use deltaz_shared::paper::{
    table2_exterior, table4_direction, DC40_GRID, TABLE1_INNER, TABLE3_GLOBAL,
};
use deltaz_shared::projector::{Projector, ProjectorRay};
use deltaz_shared::rig::{Method, Rig};
use nalgebra::Vector3;

/// The id of the smoke dot, carrying Table 4's ray "12".
pub const RAY: u16 = 12;

/// Index of ray "12" in [`TABLE4`](deltaz_shared::paper::TABLE4).
const TABLE4_RAY_12: usize = 4;

/// The paper's camera: Table 1 inner orientation, Table 2's 1st-plane exterior orientation.
pub fn paper_camera() -> Camera<f64> {
    Camera {
        grid: DC40_GRID,
        inner: TABLE1_INNER,
        exterior: table2_exterior(0),
    }
}

/// The paper's rig in f64: [`paper_camera`], Table 3's projector centre and Table 4's ray "12".
pub fn paper_rig() -> Rig<f64, [ProjectorRay<f64>; 1]> {
    let Camera {
        grid,
        inner,
        exterior,
    } = paper_camera();
    let ray = ProjectorRay {
        id: RAY,
        direction: table4_direction(TABLE4_RAY_12),
        offset: Vector3::zeros(),
    };
    let projector = Projector::new(Vector3::from(TABLE3_GLOBAL), [ray])
        .unwrap_or_else(|_| unreachable!("a valid one-ray table"));
    Rig::new(grid, inner, &exterior, projector)
}

/// [`paper_rig`] cast to f32 after centring in f64, as an upload does ([`Rig::cast`]).
pub fn paper_rig_f32() -> Option<Rig<f32, heapless::Vec<ProjectorRay<f32>, 1>>> {
    paper_rig().cast().ok()
}

/// The pixel (col, row) where the camera sees ray 12 hit the plate Z = 0 (f64).
pub fn smoke_pixel() -> Option<(f64, f64)> {
    let ray = paper_rig().projector_centred().ray(RAY).ok()?;
    let centre = paper_camera().exterior.centre;
    let on_plate = ray.at(-(ray.point.z + centre.z) / ray.direction.z) + centre;
    paper_camera().world_to_pixel(&on_plate).ok()
}

/// The smoke point in f32 (world mm), or `None` if the geometry were degenerate.
pub fn smoke_point() -> Option<Vector3<f32>> {
    let (col, row) = smoke_pixel()?;
    paper_rig_f32()?
        .reconstruct(RAY, col as f32, row as f32, Method::ClosestApproach)
        .ok()
        .map(|hit| hit.point)
}
