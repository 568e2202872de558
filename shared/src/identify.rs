//! Epipolar identification of projected dots: which projector ray made each detected dot.
//!
//! With a calibrated system, the image of projector ray k over the working depth range is a short
//! epipolar segment: the camera's image (eq. 1 with distortion) of the ray's points
//! X = X_p + λ (l, m, n) (eq. 5) between the near and far depth. A dot belongs to the ray whose
//! segment passes within the tolerance; if two segments do, the dot is *ambiguous*, if none does it
//! is *unassigned*, and if two dots claim one ray both are *conflicts*: nothing is guessed.
//!
//! Lens distortion bends the segments in the observed image, but not in the *refined* one (the
//! image eq. (1) predicts, distortion and principal point removed: [`crate::camera`]): the
//! pinhole image of a line is a line. So each dot is refined once, and each segment is kept as
//! its two ends in refined pixel positions (the refined photo coordinates on the sensor's
//! raster), 8 bytes in i16 fixed point. A lookup grid over the refined image, built once when
//! the calibration is loaded, lists for every cell the rays whose segment passes within the
//! tolerance of it; a dot is then compared only with its own cell's few candidates. Everything
//! lives in fixed-capacity arrays (no allocator): `R` rays, `C` grid cells and `E` cell entries
//! in all. When the requested cell size needs more cells or entries than that, the grid's cells
//! grow (by a quarter at a time) until it fits: a longer depth range costs comparisons per dot,
//! not a refusal ([`Identifier::cell`] gives the size used).
//!
//! # What the pattern and the geometry must give
//! Two rays whose segments come within twice the tolerance of each other cannot be told apart
//! where they do. With a camera-projector baseline along the image rows, the dots of one pattern
//! row share one epipolar line: their segments must then not overlap along it, which limits the
//! depth range to about one column pitch of disparity. Rotating the pattern against the baseline
//! separates the lines of neighbouring columns, so the depth range may span several column
//! pitches (the paper's rows, Table 4, are turned by about 1.6°: enough for torso frames spanning
//! 160 mm, see the host's identification tests); [`Identifier::close_pairs`] counts the pairs of
//! rays that come too close, to check a design.

use crate::camera::{InnerOrientation, PixelGrid};
use crate::collinearity::project_camera_point;
use crate::epipolar::segments_distance;
pub use crate::epipolar::EpipolarSegment;
use crate::projector::{ProjectorRay, RayStore};
use crate::rig::Rig;
use crate::{lit, sqrt, Error};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use nalgebra::{RealField, Vector2};
use simba::scalar::SupersetOf;

/// How much a grid cell grows per try when the grid does not fit its capacities (5/4).
const GROWTH: f32 = 1.25;

/// The working depth range: distances from the camera's perspective centre along its viewing
/// axis (mm), near < far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthRange<T> {
    /// Nearest surface distance (mm).
    pub near: T,
    /// Farthest surface distance (mm).
    pub far: T,
}

/// Why an identifier cannot be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum IdentifyError {
    /// The projector has more rays than the identifier's capacity `R`.
    TooManyRays,
    /// The segments fill more cell entries than the capacity `E` even in one cell as large as
    /// the image (`E` is below the number of rays).
    TooManyEntries,
    /// The depth range is not near < far with near > 0, or the tolerance or cell size is not
    /// positive.
    InvalidParameters,
    /// A ray's segment cannot be imaged (it passes behind the camera, or the geometry fails).
    Geometry(u16, Error),
}

impl core::fmt::Display for IdentifyError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            IdentifyError::TooManyRays => {
                f.write_str("more projector rays than the identifier holds")
            }
            IdentifyError::TooManyEntries => f.write_str(
                "the epipolar segments need more grid entries than the identifier holds",
            ),
            IdentifyError::InvalidParameters => {
                f.write_str("need 0 < near < far, a positive tolerance and a positive cell size")
            }
            IdentifyError::Geometry(id, e) => write!(f, "ray {id}: its epipolar segment: {e}"),
        }
    }
}

/// The result for one dot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Assignment<T> {
    /// The dot belongs to this ray; `distance` from its segment (pixels).
    Ray {
        /// The ray id.
        id: u16,
        /// Distance of the dot from the ray's epipolar segment (pixels).
        distance: T,
    },
    /// Two or more segments pass within tolerance: the two closest.
    Ambiguous {
        /// The closest ray.
        first: u16,
        /// The second closest.
        second: u16,
    },
    /// Another dot of the same frame was assigned the same ray: neither is trusted.
    Conflict {
        /// The ray both dots claim.
        id: u16,
    },
    /// No segment passes within tolerance (clutter, or a surface outside the depth range).
    Unassigned,
}

impl<T> Assignment<T> {
    /// The ray id if the dot was identified.
    pub fn id(&self) -> Option<u16> {
        match self {
            Assignment::Ray { id, .. } => Some(*id),
            _ => None,
        }
    }
}

/// An epipolar segment as the identifier keeps it: (col, row) of its two ends in i16 fixed point
/// (8 bytes instead of 16 in f32).
type Polyline = [[i16; 2]; 2];

/// The fixed-point step of the segments for a sensor `extent` pixels wide (its larger side):
/// 1/16 pixel while ±2 extents fit the i16 range (up to 1023 pixels), 1/8 up to 2047 pixels,
/// coarser above. Rounding moves an end by at most half a step (1/32 or 1/16 pixel per axis), a
/// few per cent of a tolerance.
fn fixed_point_unit<T: RealField + Copy + SupersetOf<f32>>(extent: u32) -> T {
    let mut bits = 4;
    while bits > 0 && (2 * u64::from(extent)) << bits > i16::MAX as u64 {
        bits -= 1;
    }
    nalgebra::convert::<f32, T>(1.0 / (1u32 << bits) as f32)
}

/// Dot identification by epipolar segments with a lookup grid; capacities: `R` rays, `C` cells,
/// `E` cell entries.
#[derive(Debug, Clone)]
pub struct Identifier<T: RealField, const R: usize, const C: usize, const E: usize> {
    /// Each ray's epipolar segment in i16 fixed point of `unit` pixels (see [`Polyline`]).
    polylines: [Polyline; R],
    /// The rays' ids, in the projector's order.
    ids: [u16; R],
    /// Pixels per fixed-point step of `polylines`.
    unit: T,
    rays: usize,
    /// The raster and inner orientation that refine a dot.
    grid: PixelGrid<T>,
    inner: InnerOrientation<T>,
    tolerance: T,
    cell: T,
    /// The refined pixel position of the grid's first cell's corner.
    origin: Vector2<T>,
    grid_cols: usize,
    grid_rows: usize,
    /// Where each cell's entries start in `entries` (they end where the next cell's start).
    starts: [u16; C],
    total: u16,
    entries: [u16; E],
}

impl<T: RealField + Copy + SupersetOf<f32>, const R: usize, const C: usize, const E: usize>
    Identifier<T, R, C, E>
{
    /// Build the segments of every ray of `rig` over `depth`, and the lookup grid of square
    /// cells of side `cell` pixels. `tolerance` (pixels) is the largest distance of a dot from
    /// its ray's segment: a few σ of the centroid noise plus the calibration's image error.
    pub fn new<S: RayStore<T>>(
        rig: &Rig<T, S>,
        depth: DepthRange<T>,
        tolerance: T,
        cell: T,
    ) -> Result<Self, IdentifyError> {
        let mut me = Self::empty();
        me.rebuild(rig, depth, tolerance, cell)?;
        Ok(me)
    }

    /// An identifier of no rays: every dot is unassigned.
    pub fn empty() -> Self {
        let mut slot = MaybeUninit::uninit();
        Self::empty_in(&mut slot);
        // SAFETY: `empty_in` wrote every field.
        unsafe { slot.assume_init() }
    }

    /// [`Self::empty`] written in place into `slot` (a device's static): the tables go straight
    /// into their memory, no copy of them passes through the stack.
    pub fn empty_in(slot: &mut MaybeUninit<Self>) -> &mut Self {
        // Ray indices and entry positions are u16.
        const { assert!(R <= u16::MAX as usize, "at most 65535 rays") };
        const { assert!(E <= u16::MAX as usize, "at most 65535 entries") };
        let me = slot.as_mut_ptr();
        // SAFETY: every field of `*me` is written through a raw pointer to it (no reference to
        // uninitialised memory is made), the arrays element by element (zero bytes are a valid
        // u16), before `assume_init_mut`.
        unsafe {
            addr_of_mut!((*me).polylines).write_bytes(0, 1);
            addr_of_mut!((*me).ids).write_bytes(0, 1);
            addr_of_mut!((*me).unit).write(T::one());
            addr_of_mut!((*me).rays).write(0);
            addr_of_mut!((*me).grid).write(PixelGrid {
                pixel_size: T::one(),
                width: 0,
                height: 0,
                origin_col: T::zero(),
                origin_row: T::zero(),
            });
            addr_of_mut!((*me).inner).write(InnerOrientation::ideal(T::one()));
            addr_of_mut!((*me).tolerance).write(T::one());
            addr_of_mut!((*me).cell).write(T::one());
            addr_of_mut!((*me).origin).write(Vector2::zeros());
            addr_of_mut!((*me).grid_cols).write(0);
            addr_of_mut!((*me).grid_rows).write(0);
            addr_of_mut!((*me).starts).cast::<u16>().write_bytes(0, C);
            addr_of_mut!((*me).total).write(0);
            addr_of_mut!((*me).entries).cast::<u16>().write_bytes(0, E);
            slot.assume_init_mut()
        }
    }

    /// [`Self::new`] in place, for a device that keeps its identifier where it lives instead of
    /// moving the whole table. On failure the identifier is left empty.
    pub fn rebuild<S: RayStore<T>>(
        &mut self,
        rig: &Rig<T, S>,
        depth: DepthRange<T>,
        tolerance: T,
        cell: T,
    ) -> Result<(), IdentifyError> {
        let result = self.fill(rig, depth, tolerance, cell);
        if result.is_err() {
            self.clear();
        }
        result
    }

    /// Forget every ray: every dot is unassigned.
    pub fn clear(&mut self) {
        self.rays = 0;
        self.total = 0;
        self.grid_cols = 0;
        self.grid_rows = 0;
    }

    fn fill<S: RayStore<T>>(
        &mut self,
        rig: &Rig<T, S>,
        depth: DepthRange<T>,
        tolerance: T,
        cell: T,
    ) -> Result<(), IdentifyError> {
        let store = rig.projector_centred().store();
        if store.count() > R {
            return Err(IdentifyError::TooManyRays);
        }
        let valid = depth.near > T::zero()
            && depth.far > depth.near
            && tolerance > T::zero()
            && cell > T::zero();
        if !valid {
            return Err(IdentifyError::InvalidParameters);
        }
        let grid = *rig.grid();
        self.grid = grid;
        self.inner = *rig.inner();
        self.tolerance = tolerance;
        let unit = fixed_point_unit(grid.width.max(grid.height));
        self.unit = unit;
        let slots = self.polylines.iter_mut().zip(self.ids.iter_mut());
        let mut rays = 0;
        for (k, (line, id)) in (0..store.count()).zip(slots) {
            let ray = store
                .ray_at(k)
                .ok_or(IdentifyError::Geometry(0, Error::InvalidCalibration))?;
            let segment = epipolar_segment(rig, &ray, depth)
                .map_err(|e| IdentifyError::Geometry(ray.id, e))?;
            *line = segment.points.map(|p| [p.x, p.y].map(|v| fixed(v, unit)));
            *id = ray.id;
            rays += 1;
        }
        self.rays = rays;
        // The refined image of the sensor (its corners and edge middles, a pixel around).
        // (In f32 constants: no f64 arithmetic on the device.)
        let f = nalgebra::convert::<f32, T>;
        let (mut lo, mut hi) = (Vector2::repeat(f(1e30)), Vector2::repeat(f(-1e30)));
        let (w, h) = (f(grid.width as f32), f(grid.height as f32));
        for (c, r) in [(0.0, 0.0), (0.5, 0.0), (1.0, 0.0), (0.0, 0.5)]
            .into_iter()
            .chain([(1.0, 0.5), (0.0, 1.0), (0.5, 1.0), (1.0, 1.0)])
        {
            let p = self.refined(w * f(c) - f(0.5), h * f(r) - f(0.5));
            lo = lo.inf(&p);
            hi = hi.sup(&p);
        }
        self.origin = lo - Vector2::repeat(T::one());
        let extent = hi - self.origin + Vector2::repeat(T::one());
        // The cells grow until the grid fits: cells, then entries.
        let largest = extent.x.max(extent.y);
        let mut side = cell;
        loop {
            self.cell = side;
            self.grid_cols = cells_along(extent.x, side);
            self.grid_rows = cells_along(extent.y, side);
            if self.grid_cols * self.grid_rows <= C {
                match self.count_entries() {
                    Some(total) => {
                        self.total = total as u16;
                        break;
                    }
                    None if side > largest => return Err(IdentifyError::TooManyEntries),
                    None => {}
                }
            }
            side *= nalgebra::convert::<f32, T>(GROWTH);
        }
        // Each cell's slots from its end down, the rays in reverse: every cell lists its rays
        // in order. Cells are below C and entries below E (counted), so the `get`s always find
        // theirs.
        for k in (0..self.rays).rev() {
            if let Some(segment) = self.segment(k) {
                self.for_each_cell(&segment, |me, cell| {
                    if let Some(start) = me.starts.get_mut(cell) {
                        *start = start.wrapping_sub(1);
                        if let Some(entry) = me.entries.get_mut(usize::from(*start)) {
                            *entry = k as u16;
                        }
                    }
                });
            }
        }
        Ok(())
    }

    /// Count the entries of the current grid: each cell's start set to the end of its entries.
    /// `None` (the starts left spoilt) when they exceed `E`.
    fn count_entries(&mut self) -> Option<usize> {
        self.starts.fill(0);
        for k in 0..self.rays {
            if let Some(segment) = self.segment(k) {
                self.for_each_cell(&segment, |me, cell| {
                    if let Some(start) = me.starts.get_mut(cell) {
                        *start = start.saturating_add(1);
                    }
                });
            }
        }
        let mut total = 0usize;
        for start in self.starts.iter_mut().take(self.grid_cols * self.grid_rows) {
            total += usize::from(*start);
            if total > E {
                return None;
            }
            *start = total as u16;
        }
        Some(total)
    }

    /// The side (pixels) of the grid's cells: the requested one, or larger when the grid would
    /// not fit its capacities with it.
    pub fn cell(&self) -> T {
        self.cell
    }

    /// A dot's refined pixel position (see the module docs).
    fn refined(&self, col: T, row: T) -> Vector2<T> {
        let (c, r) = self
            .grid
            .photo_to_pixel(self.inner.refine(self.grid.pixel_to_photo(col, row)));
        Vector2::new(c, r)
    }

    /// Visit every grid cell the segment passes within the tolerance of.
    fn for_each_cell(
        &mut self,
        segment: &EpipolarSegment<T>,
        mut visit: impl FnMut(&mut Self, usize),
    ) {
        let reach = self.tolerance;
        let [a, b] = segment.points;
        let Some((c0, r0)) = self.cell_of_clamped(a.inf(&b) - Vector2::repeat(reach)) else {
            return;
        };
        let Some((c1, r1)) = self.cell_of_clamped(a.sup(&b) + Vector2::repeat(reach)) else {
            return;
        };
        for r in r0..=r1 {
            for c in c0..=c1 {
                let corner =
                    self.origin + Vector2::new(lit::<T>(c as f64), lit::<T>(r as f64)) * self.cell;
                if segment.meets(corner, self.cell, reach) {
                    visit(self, r * self.grid_cols + c);
                }
            }
        }
    }

    /// The grid cell of a refined position, clamped to the grid; `None` if not finite.
    fn cell_of_clamped(&self, p: Vector2<T>) -> Option<(usize, usize)> {
        let q = (p - self.origin) / self.cell;
        let (c, r) = (q.x.floor(), q.y.floor());
        if !(c.is_finite() && r.is_finite()) {
            return None;
        }
        let clamp = |v: T, n: usize| -> usize {
            let v = v.max(T::zero()).min(lit::<T>((n - 1) as f64));
            // A small non-negative integer here.
            small_index(v)
        };
        Some((clamp(c, self.grid_cols), clamp(r, self.grid_rows)))
    }

    /// The grid cell of a refined dot position, `None` outside the grid.
    fn cell_of(&self, p: Vector2<T>) -> Option<usize> {
        let q = (p - self.origin) / self.cell;
        let inside = q.x >= T::zero()
            && q.y >= T::zero()
            && q.x < lit::<T>(self.grid_cols as f64)
            && q.y < lit::<T>(self.grid_rows as f64);
        if !inside {
            return None;
        }
        // q ≥ 0 here, so truncation is the floor (no `floorf`, `fminf`, `fmaxf` calls on the
        // device); the far edge can round up to n.
        let index = |v: T, n: usize| small_index(v).min(n - 1);
        Some(index(q.y, self.grid_rows) * self.grid_cols + index(q.x, self.grid_cols))
    }

    /// The epipolar segments, in the projector's ray order (as stored: ends in fixed point).
    pub fn segments(&self) -> impl Iterator<Item = EpipolarSegment<T>> + '_ {
        (0..self.rays).filter_map(|k| self.segment(k))
    }

    /// Ray `k`'s polyline in pixels (`None` beyond the capacity, which `rays` never is).
    fn segment(&self, k: usize) -> Option<EpipolarSegment<T>> {
        let line = self.polylines.get(k)?;
        Some(EpipolarSegment {
            id: *self.ids.get(k)?,
            points: line.map(|[x, y]| Vector2::new(self.pixels(x), self.pixels(y))),
        })
    }

    /// A fixed-point coordinate in pixels.
    fn pixels(&self, q: i16) -> T {
        nalgebra::convert::<f32, T>(f32::from(q)) * self.unit
    }

    /// Total cell entries of the lookup grid (its memory use beyond the segments).
    pub fn entries(&self) -> usize {
        usize::from(self.total)
    }

    /// The entries of grid cell `cell`.
    fn cell_entries(&self, cell: usize) -> &[u16] {
        let start = self.starts.get(cell).map_or(0, |&s| usize::from(s));
        let end = match self.starts.get(cell + 1) {
            Some(&next) if cell + 1 < self.grid_cols * self.grid_rows => usize::from(next),
            _ => usize::from(self.total),
        };
        self.entries.get(start..end).unwrap_or_default()
    }

    /// The assignment of one dot at pixel (col, row), by itself (see [`Self::identify_frame`]).
    pub fn identify(&self, col: T, row: T) -> Assignment<T> {
        self.nearest(self.refined(col, row)).0
    }

    /// Like [`Self::identify`] of a refined position, with the ray's index in
    /// [`Self::segments`].
    fn nearest(&self, p: Vector2<T>) -> (Assignment<T>, usize) {
        let Some(cell) = self.cell_of(p) else {
            return (Assignment::Unassigned, 0);
        };
        // Squared distances (pixels²): one square root, for the ray found.
        let limit = self.tolerance * self.tolerance;
        // (squared distance, ray index, ray id)
        let mut first: Option<(T, usize, u16)> = None;
        let mut second: Option<(T, usize, u16)> = None;
        for &k in self.cell_entries(cell) {
            let k = usize::from(k);
            let Some(segment) = self.segment(k) else {
                continue;
            };
            let d = segment.distance_squared(p);
            if d > limit {
                continue;
            }
            match first {
                Some((d1, ..)) if d >= d1 => {
                    if second.is_none_or(|(d2, ..)| d < d2) {
                        second = Some((d, k, segment.id));
                    }
                }
                _ => {
                    second = first;
                    first = Some((d, k, segment.id));
                }
            }
        }
        match (first, second) {
            (Some((_, a, first)), Some((.., second))) => {
                (Assignment::Ambiguous { first, second }, a)
            }
            (Some((d, a, id)), None) => (
                Assignment::Ray {
                    id,
                    distance: sqrt(d),
                },
                a,
            ),
            _ => (Assignment::Unassigned, 0),
        }
    }

    /// Identify all dots of one frame (pixel positions (col, row)) into `out` (same length):
    /// each dot by [`Self::identify`], then every ray claimed by more than one dot turned into
    /// [`Assignment::Conflict`] for all of them. Returns the number identified.
    pub fn identify_frame(&self, dots: &[(T, T)], out: &mut [Assignment<T>]) -> usize {
        self.identify_each(dots.iter().copied(), out)
    }

    /// [`Self::identify_frame`] of dots from an iterator (a device reads them from its receive
    /// buffer): as many as `out` holds.
    pub fn identify_each(
        &self,
        dots: impl IntoIterator<Item = (T, T)>,
        out: &mut [Assignment<T>],
    ) -> usize {
        let mut claims = [0u8; R];
        let mut n = 0;
        for (dot, slot) in dots.into_iter().zip(out.iter_mut()) {
            let (assignment, k) = self.nearest(self.refined(dot.0, dot.1));
            if let (Assignment::Ray { .. }, Some(claim)) = (assignment, claims.get_mut(k)) {
                *claim = claim.saturating_add(1);
            }
            *slot = assignment;
            n += 1;
        }
        let mut identified = 0;
        for slot in out.iter_mut().take(n) {
            if let Assignment::Ray { id, .. } = *slot {
                let ids = self.ids.get(..self.rays).unwrap_or_default();
                let k = ids.binary_search(&id).unwrap_or(0);
                if claims.get(k).is_some_and(|&c| c > 1) {
                    *slot = Assignment::Conflict { id };
                } else {
                    identified += 1;
                }
            }
        }
        identified
    }

    /// Pairs of rays whose segments come within twice the tolerance of each other somewhere: the
    /// places a dot could be ambiguous. Zero for a pattern and depth range that identify every
    /// dot.
    pub fn close_pairs(&self) -> usize {
        let limit = self.tolerance + self.tolerance;
        let mut pairs = 0;
        for (i, a) in self.segments().enumerate() {
            for b in self.segments().skip(i + 1) {
                if segments_distance(&a, &b) <= limit {
                    pairs += 1;
                }
            }
        }
        pairs
    }
}

/// Cells of side `cell` covering `extent` pixels (at most 2¹⁶: the cell counts fit u16 starts).
fn cells_along<T: RealField + Copy + SupersetOf<f32>>(extent: T, cell: T) -> usize {
    let cells = (extent / cell)
        .ceil()
        .min(nalgebra::convert::<f32, T>(65536.0));
    small_index(cells).max(1)
}

/// A pixel coordinate in the polylines' fixed point of `unit` pixels (rounded; clamped to the
/// i16 range).
fn fixed<T: RealField + Copy + SupersetOf<f32>>(v: T, unit: T) -> i16 {
    let steps = nalgebra::try_convert::<T, f32>(v / unit).unwrap_or(0.0);
    libm::roundf(steps).clamp(f32::from(i16::MIN), f32::from(i16::MAX)) as i16
}

/// A small non-negative whole number (a cell index or count) as an index, through f32 (exact
/// below 2²⁴; no f64 on the device); NaN and negative values give 0.
fn small_index<T: SupersetOf<f32>>(v: T) -> usize {
    nalgebra::try_convert::<T, f32>(v).map_or(0, |v| v as usize)
}

/// The epipolar segment of one ray: the refined pixel positions of its points at the near and
/// the far depth ([`Rig::point_at_depth`], then eq. (1) without distortion).
fn epipolar_segment<T: RealField + Copy, S: RayStore<T>>(
    rig: &Rig<T, S>,
    ray: &ProjectorRay<T>,
    depth: DepthRange<T>,
) -> Result<EpipolarSegment<T>, Error> {
    let mut points = [Vector2::zeros(); 2];
    for (out, d) in points.iter_mut().zip([depth.near, depth.far]) {
        let cam = rig.r_cam_world() * rig.point_at_depth(ray.id, d)?;
        let (col, row) = rig
            .grid()
            .photo_to_pixel(project_camera_point(rig.inner().f, &cam)?);
        *out = Vector2::new(col, row);
    }
    Ok(EpipolarSegment { id: ray.id, points })
}
