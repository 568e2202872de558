//! Figures of the back analysis against the model: each index's RMS error and RMS error/σ per
//! deformity at one dot spacing, the draws the analysis refused (a clear error, as at 40 mm,
//! where a back spans under 8 dot spacings), and the time of one analysis.
//!
//!     cargo run --release -p deltaz-host --example back_figures -- [SPACING_MM] [DRAWS]

#[path = "../tests/it/back_sim.rs"]
#[allow(dead_code)]
mod back_sim;
// back_sim's honesty assert (unused here).
#[path = "../tests/it/honesty.rs"]
#[allow(dead_code)]
mod honesty;

use back_sim::{back_dots, common_draw, frame, rng, scanned, Errors, Given, IndexErrors, Noise};
use deltaz_host::simulate::back::{BackModel, Deformity};
use deltaz_surface::{analyse, Options};
use std::time::Instant;

fn main() {
    let arg = |k: usize, default: f64| {
        std::env::args()
            .nth(k)
            .map_or(default, |s| s.parse().expect("a number"))
    };
    let (spacing, draws) = (arg(1, 20.0), arg(2, 30.0) as u64);
    println!("dot spacing {spacing} mm, {draws} draws: RMS error (RMS error/σ)");
    let cell = |e: &Errors| format!("{:.3} ({:.2})", e.rms(), e.z());
    // The draws of `model` analysed with `options`, and how many the analysis refused.
    let draws_of = |model: BackModel, options: &Options| {
        let dots = [back_dots(&model, spacing)];
        let mut errors = IndexErrors::default();
        let mut refused = 0;
        for k in 0..draws {
            match scanned(&dots, Given::WithRays, &Noise::issue(), 1 + k, options) {
                Ok(a) => errors.add(&model, &a),
                Err(_) => refused += 1,
            }
        }
        (errors, refused)
    };
    for d in Deformity::all() {
        let (standing, refused_standing) =
            draws_of(BackModel::standing(d.clone()), &Options::standing());
        let (bent, refused_bent) =
            draws_of(BackModel::forward_bent(d.clone()), &Options::forward_bent());
        println!(
            "{:9} refused {refused_standing} standing, {refused_bent} bent | symmetry x mm {} | rotation ° {} | largest rotation ° {} | RMS rotation ° {} | RMS deviation mm {} | skin angle ° {} | lateral deviation mm {} | imbalance mm {} | inclination ° {} | ATR ° {} | largest ATR ° {}",
            d.name,
            cell(&standing.symmetry_x),
            cell(&standing.rotation),
            cell(&standing.rotation_max),
            cell(&standing.rotation_rms),
            cell(&standing.lateral_deviation_rms),
            cell(&standing.skin_angle),
            cell(&standing.lateral_deviation_max),
            cell(&standing.trunk_imbalance),
            cell(&standing.trunk_inclination),
            cell(&bent.atr),
            cell(&bent.atr_max),
        );
    }
    let dots = back_dots(&BackModel::standing(Deformity::thoracic()), spacing);
    let noise = Noise::issue();
    let mut r = rng(1);
    let delta = common_draw(&noise, &mut r);
    let f = frame(&dots, &noise, &delta, &mut r);
    if let Err(e) = analyse(std::slice::from_ref(&f), &Options::standing()) {
        println!("one analysis of {} dots: refused ({e})", f.points.len());
        return;
    }
    let runs = 10;
    let start = Instant::now();
    for _ in 0..runs {
        analyse(std::slice::from_ref(&f), &Options::standing()).expect("analysed");
    }
    println!(
        "one analysis of {} dots: {:.0} ms",
        f.points.len(),
        start.elapsed().as_secs_f64() * 1e3 / runs as f64
    );
}
