//! Detections that disagree with their own population: a blob can pass every test of its own
//! (area, ellipse shape, template residual, template against gravity centre) and still not be a
//! target, as a speck of a textured background a few DN deep beside targets 150 DN deep is not.
//! What tells it apart is its contrast against the targets around it, so the test is local:
//! illumination that halves the contrast in a dim corner halves it for every target there.
//!
//! For each accepted target with amplitude a (the template's, or the blob's peak for the gravity
//! method) the local level L is the median amplitude of its [`NEIGHBOURS`] nearest targets, and
//! ρ = ln(a / L). Over the image the ρ of real targets cluster about 0 (their spread is the
//! amplitude noise, the printing and the illumination's change from one target to the next); a
//! target is rejected as [`Rejection::Faint`] when its ρ is both below the image's median ρ by
//! more than 5 robust σ (MAD · 1.4826) and below ln ⅓: fainter than a third of its neighbours'
//! level (a real target in a glare or a shadow keeps half of it; a speck 10-40 DN deep beside
//! targets 150 DN deep has a tenth to a quarter), and an outlier of the image's own spread of ρ.

use super::detect::{Blob, Rejection};
use super::{median, Target};
use rayon::prelude::*;

/// The neighbours whose median amplitude is a target's local level.
pub const NEIGHBOURS: usize = 8;

/// Fewer targets than this are not tested (no population to agree with).
const MIN_POPULATION: usize = 2 * NEIGHBOURS;

/// The amplitude of a target: the template fit's, or the blob's peak (DN).
fn amplitude(t: &Target) -> f64 {
    t.fit.map_or(t.blob.peak, |f| f.amplitude)
}

/// The targets that agree with their population, and those rejected as [`Rejection::Faint`]
/// (see the module's doc). The targets keep their order.
pub fn gate_faint(targets: Vec<Target>) -> (Vec<Target>, Vec<(Blob, Rejection)>) {
    if targets.len() < MIN_POPULATION {
        return (targets, Vec::new());
    }
    let points: Vec<(f64, f64)> = targets.iter().map(|t| (t.col, t.row)).collect();
    let amplitudes: Vec<f64> = targets.iter().map(amplitude).collect();
    let cells = Cells::new(&points);
    let ratios: Vec<f64> = (0..targets.len())
        .into_par_iter()
        .map_init(Vec::new, |buf, i| {
            let mut levels: Vec<f64> = cells
                .nearest(&points, i, NEIGHBOURS, buf)
                .iter()
                .map(|&j| amplitudes[j])
                .collect();
            let level = median(&mut levels);
            (amplitudes[i].max(f64::MIN_POSITIVE) / level.max(f64::MIN_POSITIVE)).ln()
        })
        .collect();
    let mut sorted = ratios.clone();
    let mid = median(&mut sorted);
    let mut deviations: Vec<f64> = ratios.iter().map(|r| (r - mid).abs()).collect();
    let spread = 1.4826 * median(&mut deviations);
    let limit = (mid - 5.0 * spread).min(-(3f64.ln()));
    let mut kept = Vec::with_capacity(targets.len());
    let mut faint = Vec::new();
    for (t, r) in targets.into_iter().zip(ratios) {
        if r < limit {
            faint.push((t.blob, Rejection::Faint));
        } else {
            kept.push(t);
        }
    }
    (kept, faint)
}

/// Points binned in square cells of about two points each, for nearest-neighbour queries.
struct Cells {
    size: f64,
    origin: (f64, f64),
    nx: usize,
    ny: usize,
    /// The points of cell (x, y) are `order[start[y * nx + x]..start[y * nx + x + 1]]`.
    start: Vec<usize>,
    order: Vec<usize>,
}

impl Cells {
    fn new(points: &[(f64, f64)]) -> Self {
        let (mut lo, mut hi) = (
            (f64::INFINITY, f64::INFINITY),
            (f64::NEG_INFINITY, f64::NEG_INFINITY),
        );
        for &(c, r) in points {
            lo = (lo.0.min(c), lo.1.min(r));
            hi = (hi.0.max(c), hi.1.max(r));
        }
        let (w, h) = ((hi.0 - lo.0).max(1.0), (hi.1 - lo.1).max(1.0));
        let size = (2.0 * w * h / points.len() as f64).sqrt().max(1.0);
        let (nx, ny) = ((w / size) as usize + 1, (h / size) as usize + 1);
        let cell = |&(c, r): &(f64, f64)| {
            let x = (((c - lo.0) / size) as usize).min(nx - 1);
            let y = (((r - lo.1) / size) as usize).min(ny - 1);
            y * nx + x
        };
        let mut start = vec![0; nx * ny + 1];
        for p in points {
            start[cell(p) + 1] += 1;
        }
        for k in 0..nx * ny {
            start[k + 1] += start[k];
        }
        let mut next = start.clone();
        let mut order = vec![0; points.len()];
        for (i, p) in points.iter().enumerate() {
            let k = cell(p);
            order[next[k]] = i;
            next[k] += 1;
        }
        Self {
            size,
            origin: lo,
            nx,
            ny,
            start,
            order,
        }
    }

    /// The `k` points nearest to point `i` (itself left out), searched ring by ring of cells
    /// until no point of a farther ring can be nearer; `buf` is scratch space.
    fn nearest(
        &self,
        points: &[(f64, f64)],
        i: usize,
        k: usize,
        buf: &mut Vec<(f64, usize)>,
    ) -> Vec<usize> {
        let (c, r) = points[i];
        let x = (((c - self.origin.0) / self.size) as usize).min(self.nx - 1) as i64;
        let y = (((r - self.origin.1) / self.size) as usize).min(self.ny - 1) as i64;
        buf.clear();
        let rings = self.nx.max(self.ny) as i64;
        for ring in 0..=rings {
            for cy in y - ring..=y + ring {
                for cx in x - ring..=x + ring {
                    let on_ring = (cy - y).abs() == ring || (cx - x).abs() == ring;
                    if !on_ring || cx < 0 || cy < 0 || cx >= self.nx as i64 || cy >= self.ny as i64
                    {
                        continue;
                    }
                    let cell = cy as usize * self.nx + cx as usize;
                    for &j in &self.order[self.start[cell]..self.start[cell + 1]] {
                        if j != i {
                            let (pc, pr) = points[j];
                            buf.push(((pc - c).powi(2) + (pr - r).powi(2), j));
                        }
                    }
                }
            }
            // Every point outside the rings searched is farther than `ring` cells.
            if buf.len() >= k {
                buf.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
                let reach = ring as f64 * self.size;
                if buf[k - 1].0 <= reach * reach {
                    break;
                }
            }
        }
        buf.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        buf.iter().take(k).map(|&(_, j)| j).collect()
    }
}

#[cfg(test)]
mod tests {
    use crate::bench::centre_errors;
    use crate::detect::{GrayView, Polarity};
    use crate::render::{Background, Scene, Spot};
    use crate::{measure, MeasureParams};

    /// Uniform numbers in [0, 1) from a fixed linear congruential sequence.
    struct Numbers(u64);

    impl Numbers {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// A dot plate (dark dots of radius 6 px, 150 DN deep at the bright corner, on a 30 px
    /// pitch) lit unevenly: the plate's brightness, and with it the dots' depth, falls to half
    /// in the bottom-right corner. Its textured background: 4,000 faint blots (radius 1-5 px,
    /// ±2-6 DN) and `specks` dark specks 3-5 px across and 10-40 DN deep (at the bright corner,
    /// lit as the plate) between the dots. Blur σ 1 px, noise σ 2 DN. The scene and the dots.
    fn textured_plate(specks: usize) -> (Scene, Vec<Spot>) {
        let (width, height, pitch) = (960, 720, 30.0);
        // The plate's brightness: 200 DN at the top-left corner, 100 at the bottom-right.
        let light = |c: f64, r: f64| 200.0 - 50.0 * (c / width as f64 + r / height as f64);
        let mut dots = Vec::new();
        for j in 1..(height as f64 / pitch) as usize {
            for i in 1..(width as f64 / pitch) as usize {
                let phase = ((i * 7 + j * 13) % 10) as f64 / 10.0;
                let (c, r) = (i as f64 * pitch + phase, j as f64 * pitch + 0.6 * phase);
                dots.push(Spot::circle(c, r, 6.0, -0.75 * light(c, r)));
            }
        }
        let mut rand = Numbers(7);
        let mut spots = dots.clone();
        for _ in 0..4000 {
            let (c, r) = (rand.next() * width as f64, rand.next() * height as f64);
            let sign = if rand.next() < 0.5 { -1.0 } else { 1.0 };
            spots.push(Spot::circle(
                c,
                r,
                1.0 + 4.0 * rand.next(),
                sign * (2.0 + 4.0 * rand.next()),
            ));
        }
        let mut placed = 0;
        while placed < specks {
            let (c, r) = (rand.next() * width as f64, rand.next() * height as f64);
            let clear = dots
                .iter()
                .all(|d| (d.col - c).hypot(d.row - r) > d.semi_a + 5.0);
            if clear && c > 8.0 && r > 8.0 && c < width as f64 - 8.0 && r < height as f64 - 8.0 {
                // The texture is lit as the plate: 10-40 DN deep where the light is 200 DN.
                let radius = 1.5 + rand.next();
                let depth = (10.0 + 30.0 * rand.next()) * light(c, r) / 200.0;
                spots.push(Spot::circle(c, r, radius, -depth));
                placed += 1;
            }
        }
        let scene = Scene {
            width,
            height,
            spots,
            background: Background {
                level: 150.0,
                slope_col: -50.0 / width as f64,
                slope_row: -50.0 / height as f64,
                ripple: 0.0,
                ripple_period: 1.0,
            },
            falloff: 0.0,
            blur_sigma: 1.0,
            noise_sigma: 2.0,
            seed: 5,
        };
        (scene, dots)
    }

    /// The textured, unevenly lit plate with 300 specks: every dot found (within 0.5 px), those
    /// in the dim corner at half the contrast included, and at most 1 % of the detections
    /// false (farther than 1 px from every dot).
    #[test]
    fn textured_plate_keeps_every_dot_and_no_speck() {
        let (scene, dots) = textured_plate(300);
        let img = scene.render().to_u8();
        let view = GrayView {
            width: scene.width,
            height: scene.height,
            pixels: img.as_raw().as_slice(),
            dn: 1.0,
        };
        let mut params = MeasureParams::default();
        params.detect.polarity = Polarity::Dark;
        let m = measure(&view, &params);
        let found: Vec<(f64, f64)> = m.targets.iter().map(|t| (t.col, t.row)).collect();
        let truth = Scene {
            spots: dots.clone(),
            ..scene.clone()
        };
        let missed = centre_errors(&truth, &found)
            .iter()
            .filter(|e| e.is_none())
            .count();
        let false_found = found
            .iter()
            .filter(|(c, r)| dots.iter().all(|d| (d.col - c).hypot(d.row - r) > 1.0))
            .count();
        let rate = false_found as f64 / found.len() as f64;
        println!(
            "{} dots: {missed} missed; {} detections, {false_found} false ({:.2} %); rejected {}",
            dots.len(),
            found.len(),
            100.0 * rate,
            m.rejection_counts()
        );
        assert_eq!(missed, 0);
        assert!(rate <= 0.01, "{false_found} false of {}", found.len());
    }
}
