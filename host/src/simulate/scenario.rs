//! Scenario files (TOML): the camera, the target field and its stations, the rig, the plate and
//! its images, the noise. [`Scenario::paper`] is the paper's set-up.

use crate::io::camera_file::{InnerParams, PoseParams};
use crate::simulate::back_frames::BackSpec;
use crate::simulate::pattern::PatternSpec;
use deltaz_shared::paper::{DC40_GRID, TABLE1_INNER, TABLE2, TABLE3_CAMERA};
use serde::{Deserialize, Serialize};

/// A complete simulation set-up.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// A name for reports.
    pub name: String,
    /// Default random seed (the command line may override it).
    #[serde(default)]
    pub seed: u64,
    /// The camera.
    pub camera: CameraSpec,
    /// The target field for camera calibration.
    pub field: FieldSpec,
    /// The stations (convergent images) of the target field.
    pub stations: StationsSpec,
    /// The projector, rigid with the camera.
    pub rig: RigSpec,
    /// The calibration plate and its images.
    pub plate: PlateSpec,
    /// Measurement noise.
    pub noise: NoiseSpec,
    /// The frames of a back to render with the images (the `back` scenario).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub back: Option<BackSpec>,
}

/// The camera: raster and true inner orientation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Pixel size (mm).
    pub pixel_size: f64,
    /// [width, height] in pixels.
    pub image_size: [u32; 2],
    /// Pixel [col, row] of the photo-coordinate origin.
    pub origin: [f64; 2],
    /// The true inner orientation (keys f, cx, cy, k1, k2, k3, p1, p2; missing = 0).
    pub inner: InnerParams,
    /// The approximate focal length written to camera_init.json (mm).
    pub init_f: f64,
}

/// A target field: a grid of targets with relief.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldSpec {
    /// Extent [X, Y] (mm), centred on the origin.
    pub size: [f64; 2],
    /// Targets [per row, rows].
    pub grid: [u32; 2],
    /// Height range of the targets (mm): Z runs over 0..relief in a fixed pseudo-random pattern.
    pub relief: f64,
    /// σ of the control coordinates written to camera_control.csv (mm, per coordinate).
    pub control_sigma: f64,
}

/// Convergent stations on a cone around the field's centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationsSpec {
    /// Number of images; the first looks straight down, the others sit around a cone.
    pub count: u32,
    /// Distance from the field's centre (mm).
    pub distance: f64,
    /// Angle of the cone's stations off the vertical (rad).
    pub convergence: f64,
    /// Roll (κ about the viewing axis) of successive stations, cycled (rad).
    pub rolls: Vec<f64>,
}

/// The projector relative to the camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigSpec {
    /// Projector centre in the camera system (mm).
    pub projector_centre: [f64; 3],
    /// Projector orientation [κ, φ, ω] (rad): camera-system ray = R(κ, φ, ω) · projector-frame ray,
    /// R of eq. (2). The paper's Table 4 rays are in the 1st plate image's frame, so there this is
    /// the 1st plate image's rotation.
    pub projector_angles: [f64; 3],
    /// The dot pattern.
    pub pattern: PatternSpec,
}

/// The calibration plate: control points in the plate frame (plate surface Z = 0) and the
/// camera's pose in the plate frame for each plate image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateSpec {
    /// Control points [X, Y, Z] (mm); raised points have Z > 0.
    pub control: Vec<[f64; 3]>,
    /// σ of the plate control coordinates written to plate_control.csv (mm).
    pub control_sigma: f64,
    /// The plate's extent catching dots [Xmin, Xmax, Ymin, Ymax] (mm).
    pub extent: [f64; 4],
    /// The camera's pose in the plate frame, one per plate image (Table 2 for the paper).
    pub images: Vec<PoseParams>,
}

/// Image noise and gross errors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSpec {
    /// σ of image coordinates (pixels, per coordinate).
    pub image_sigma_px: f64,
    /// Fraction of target-field observations turned into gross errors.
    #[serde(default)]
    pub outlier_rate: f64,
    /// Displacement range of gross errors [min, max] (pixels).
    #[serde(default = "default_outlier_px")]
    pub outlier_px: [f64; 2],
}

fn default_outlier_px() -> [f64; 2] {
    [5.0, 20.0]
}

impl Scenario {
    /// The paper's rig: Table 1's camera (Kodak DC40 in "equivalent" 0.045 mm pixels), a
    /// 48-target field seen from 9 convergent stations, Table 2's three plate poses, Table 3's
    /// projector centre, Table 4's rays in a 20 × 22 pattern, 0.5 px noise.
    pub fn paper() -> Self {
        let table2 = TABLE2;
        let mut control = Vec::new();
        for y in [-40.0, 240.0, 480.0, 770.0] {
            for x in [0.0, 190.0, 375.0, 560.0, 750.0] {
                let raised = (240.0..=480.0).contains(&y) && (190.0..=560.0).contains(&x);
                control.push([x, y, if raised { 200.0 } else { 0.0 }]);
            }
        }
        Scenario {
            name: "paper".into(),
            seed: 1,
            camera: CameraSpec {
                pixel_size: DC40_GRID.pixel_size,
                image_size: [DC40_GRID.width, DC40_GRID.height],
                origin: [DC40_GRID.origin_col, DC40_GRID.origin_row],
                inner: TABLE1_INNER.into(),
                init_f: 46.0,
            },
            field: FieldSpec {
                size: [900.0, 650.0],
                grid: [8, 6],
                relief: 400.0,
                control_sigma: 0.1,
            },
            stations: StationsSpec {
                count: 9,
                distance: 1900.0,
                convergence: 0.45,
                rolls: vec![0.0, std::f64::consts::FRAC_PI_2],
            },
            rig: RigSpec {
                projector_centre: TABLE3_CAMERA,
                projector_angles: [table2[0][0], table2[0][1], table2[0][2]],
                pattern: PatternSpec::paper(),
            },
            plate: PlateSpec {
                control,
                control_sigma: 0.1,
                extent: [-400.0, 1150.0, -200.0, 950.0],
                images: table2.iter().map(|p| PoseParams::from_array(*p)).collect(),
            },
            noise: NoiseSpec {
                image_sigma_px: 0.5,
                outlier_rate: 0.0,
                outlier_px: default_outlier_px(),
            },
            back: None,
        }
    }

    /// A scenario from TOML text, validated.
    pub fn from_toml(text: &str) -> anyhow::Result<Self> {
        let scenario: Scenario = toml::from_str(text)?;
        scenario.validate()?;
        Ok(scenario)
    }

    /// Checks what [`super::simulate`] relies on: a positive pixel size and focal length, at
    /// least one plate image and one station, a field grid of at least 2 × 2, ray ids that fit
    /// row·100 + col (at most 100 columns, 655 rows), σ ≥ 0 and an outlier rate in 0..1.
    pub fn validate(&self) -> anyhow::Result<()> {
        let c = &self.camera;
        anyhow::ensure!(c.pixel_size > 0.0, "camera.pixel_size must be positive");
        anyhow::ensure!(
            c.inner.f > 0.0 && c.init_f > 0.0,
            "camera f and init_f must be positive"
        );
        anyhow::ensure!(!self.plate.images.is_empty(), "plate.images is empty");
        anyhow::ensure!(
            self.stations.count >= 1,
            "stations.count must be at least 1"
        );
        anyhow::ensure!(
            self.field.grid.iter().all(|n| *n >= 2),
            "field.grid must be at least [2, 2]"
        );
        let p = &self.rig.pattern;
        anyhow::ensure!(
            p.cols <= 100 && p.rows <= 655,
            "rig.pattern: ids are row*100 + col, so at most 100 columns and 655 rows"
        );
        anyhow::ensure!(
            self.noise.image_sigma_px >= 0.0
                && self.field.control_sigma >= 0.0
                && self.plate.control_sigma >= 0.0,
            "noise and control σ must not be negative"
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.noise.outlier_rate),
            "noise.outlier_rate must lie in 0..1"
        );
        if let Some(back) = &self.back {
            back.validate()?;
        }
        self.check_sizes()
    }

    /// Sizes and counts within limits, checked before anything is allocated or written: images
    /// of at most 50 megapixels (65,536 px a side), 10,000 stations, 1,000,000 field targets,
    /// 1,000 plate images.
    fn check_sizes(&self) -> anyhow::Result<()> {
        let [width, height] = self.camera.image_size;
        let side = crate::io::camera_file::MAX_IMAGE_SIDE;
        anyhow::ensure!(
            width.max(height) <= side && u64::from(width) * u64::from(height) <= 50_000_000,
            "camera.image_size {width} x {height} px exceeds the limit of 50 megapixels \
             ({side} px a side)"
        );
        anyhow::ensure!(
            self.stations.count <= 10_000,
            "stations.count {} exceeds the limit of 10,000",
            self.stations.count
        );
        let [cols, rows] = self.field.grid;
        anyhow::ensure!(
            u64::from(cols) * u64::from(rows) <= 1_000_000,
            "field.grid {cols} x {rows} exceeds the limit of 1,000,000 targets"
        );
        anyhow::ensure!(
            self.plate.images.len() <= 1_000,
            "plate.images: {} exceeds the limit of 1,000 images",
            self.plate.images.len()
        );
        Ok(())
    }
}

impl Scenario {
    /// A large network for benchmarks: the paper's camera and rig, `images` stations and about
    /// `targets` targets (a square-ish grid) on the paper's field.
    pub fn large(images: u32, targets: u32) -> Self {
        let mut s = Scenario::paper();
        s.name = format!("large-{images}x{targets}");
        let nx = ((f64::from(targets) * 10.0 / 7.0).sqrt().round() as u32).max(2);
        s.field.grid = [nx, targets.div_ceil(nx).max(2)];
        s.stations.count = images;
        s.stations.rolls = vec![0.0, std::f64::consts::FRAC_PI_2, -0.3, 1.2];
        s
    }
}

impl Scenario {
    /// A desk-scale rig unlike the paper's in every respect that matters to calibration: a
    /// 2448 × 2048 camera (3.45 µm pixels, f 12.3 mm, k1 only), a projector 180 mm to its left,
    /// toed in by 12°, 24 × 18 dots through a lens with radial distortion; a 500 × 400 mm plate
    /// with 20 control points, 6 of them raised 120 mm, at 5 tilted poses 550-850 mm from the
    /// camera (seen in part: some images hold one raised point, the edge rays fall on one plate),
    /// and a sixth pose ([`Scenario::DESK_HELD_OUT`]) held out for accuracy.
    pub fn desk() -> Self {
        use deltaz_shared::rotation::rotation_matrix;
        let mut control = Vec::new();
        for y in [0.0, 133.0, 267.0, 400.0] {
            for x in [0.0, 125.0, 250.0, 375.0, 500.0] {
                let raised = (y == 0.0 || y == 400.0) && (x == 0.0 || x == 500.0)
                    || (x == 250.0 && (y == 133.0 || y == 267.0));
                control.push([x, y, if raised { 120.0 } else { 0.0 }]);
            }
        }
        // (aim point on the plate, distance, κ, φ, ω): the camera looks at the aim point.
        let poses: [([f64; 2], f64, [f64; 3]); 6] = [
            ([150.0, 120.0], 550.0, [0.10, 0.20, -0.15]),
            ([330.0, 250.0], 625.0, [-0.20, -0.25, 0.10]),
            ([250.0, 200.0], 700.0, [1.50, 0.15, 0.25]),
            ([220.0, 180.0], 775.0, [0.30, -0.10, -0.30]),
            ([260.0, 210.0], 850.0, [-1.40, 0.25, 0.05]),
            ([240.0, 190.0], 720.0, [0.05, -0.20, 0.20]),
        ];
        let images = poses
            .iter()
            .map(|&([x, y], distance, [kappa, phi, omega])| {
                let r = rotation_matrix(kappa, phi, omega);
                // The camera looks along its −z: the aim point is at distance along R ᵀ(0, 0, −1).
                let centre = nalgebra::Vector3::new(x, y, 0.0) + r.transpose().column(2) * distance;
                PoseParams::from_array([kappa, phi, omega, centre.x, centre.y, centre.z])
            })
            .collect();
        let mut inner = InnerParams::from(deltaz_shared::camera::InnerOrientation::ideal(12.3));
        inner.cx = 0.021;
        inner.cy = -0.017;
        inner.k1 = -8e-4;
        Scenario {
            name: "desk".into(),
            seed: 1,
            camera: CameraSpec {
                pixel_size: 0.00345,
                image_size: [2448, 2048],
                origin: [1223.5, 1023.5],
                inner,
                init_f: 12.0,
            },
            field: FieldSpec {
                size: [600.0, 450.0],
                grid: [10, 8],
                relief: 150.0,
                control_sigma: 0.05,
            },
            stations: StationsSpec {
                count: 9,
                distance: 800.0,
                convergence: 0.5,
                rolls: vec![0.0, std::f64::consts::FRAC_PI_2],
            },
            rig: RigSpec {
                projector_centre: [-180.0, 0.0, 0.0],
                projector_angles: [0.0, 12f64.to_radians(), 0.0],
                pattern: PatternSpec {
                    rows: 18,
                    cols: 24,
                    origin: [-0.28, -0.2],
                    col_step: [0.56 / 23.0, 0.0],
                    row_step: [0.0, 0.4 / 17.0],
                    table4: false,
                    distortion: 0.15,
                    noncentral_mm: 0.0,
                },
            },
            plate: PlateSpec {
                control,
                control_sigma: 0.05,
                extent: [-40.0, 540.0, -40.0, 440.0],
                images,
            },
            noise: NoiseSpec {
                image_sigma_px: 0.5,
                outlier_rate: 0.0,
                outlier_px: default_outlier_px(),
            },
            back: None,
        }
    }

    /// The paper's rig with five plates 100 mm apart and a sixth, tilted, held out (index 5),
    /// the plate control measured to 0.01 mm.
    pub fn paper_five_plates() -> Self {
        let mut sc = Scenario::paper();
        sc.name = "paper-five-plates".into();
        sc.plate.control_sigma = 0.01;
        let base = sc.plate.images[0].to_array();
        sc.plate.images = (0..5)
            .map(|k| {
                let mut p = base;
                p[5] -= 100.0 * k as f64;
                p[1] += 0.004 * k as f64;
                PoseParams::from_array(p)
            })
            .collect();
        let mut unseen = base;
        unseen[1] += 0.05;
        unseen[3] += 60.0;
        unseen[5] -= 150.0;
        sc.plate.images.push(PoseParams::from_array(unseen));
        sc
    }

    /// The index of the desk rig's held-out plate image.
    pub const DESK_HELD_OUT: usize = 5;
}
