#[path = "../tests/it/back_sim.rs"]
#[allow(dead_code)]
mod back_sim;
use back_sim::*;
use deltaz_host::simulate::back::{Axes, BackModel, Deformity};
use deltaz_surface::{analyse, Options};
use nalgebra::Vector3;

fn main() {
    let spacing: f64 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(20.0);
    let draws: u64 = std::env::args().nth(2).map(|s| s.parse().unwrap()).unwrap_or(10);
    for d in Deformity::all() {
        let model = BackModel::forward_bent(d.clone());
        let dots = back_dots(&model, spacing);
        let noise = Noise::issue();
        let mut errs = vec![]; let mut zs = vec![]; let mut maxe = vec![];
        for k in 0..draws {
            let mut r = rng(k + 100);
            let delta = common_draw(&noise, &mut r);
            let f = frame(&dots, &noise, &delta, &mut r);
            let a = match analyse(&[f], &Options::forward_bent()) { Ok(a) => a, Err(e) => { println!("{}: {e}", d.name); continue } };
            let axes = Axes { across: Vector3::from(a.axes.across), axis: Vector3::from(a.axes.axis), up: Vector3::from(a.axes.up) };
            let mut tmax: f64 = 0.0;
            for l in &a.levels {
                let w = l.atr_window.unwrap();
                let t = model.scoliometer(&axes, l.y, (w[0], w[1])).unwrap().to_degrees();
                if t.abs() > tmax.abs() { tmax = t; }
                let e = l.atr_deg.unwrap() - t;
                errs.push(e); zs.push(e / l.atr_sigma_deg.unwrap());
                if k == 0 && std::env::var("LEVELS").is_ok() { println!("  y {:.0} atr {:.2} true {:.2} s {:.2} rot {:.2} truerot {:.2}", l.y, l.atr_deg.unwrap(), t, l.atr_sigma_deg.unwrap(), l.rotation_deg, model.rotation(&axes, l.y).unwrap().to_degrees()); }
            }
            maxe.push(a.atr_max_deg.unwrap() - tmax);
            if k == 0 { println!("axes {:?} levels {} y {:.0}..{:.0}", a.axes, a.levels.len(), a.levels[0].y, a.levels.last().unwrap().y); }
        }
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        println!("{:9} atr err rms {:.3} z {:.2} | max err rms {:.3} max abs {:.3}", d.name, rms(&errs), rms(&zs), rms(&maxe), maxe.iter().fold(0.0f64, |m, x| m.max(x.abs())));
    }
}
