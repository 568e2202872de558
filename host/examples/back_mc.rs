#[path = "../tests/it/back_sim.rs"]
#[allow(dead_code)]
mod back_sim;
use back_sim::*;
use deltaz_host::simulate::back::{Axes, BackModel, Deformity, Part};
use deltaz_surface::{analyse, Options};

fn main() {
    let spacing: f64 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(20.0);
    let smoothing: f64 = std::env::args().nth(2).map(|s| s.parse().unwrap()).unwrap_or(1.0);
    let draws: u64 = std::env::args().nth(3).map(|s| s.parse().unwrap()).unwrap_or(30);
    for d in Deformity::all() {
        let mut model = BackModel::standing(d.clone());
        if let Ok(g) = std::env::var("GW") { model.trunk.groove_width = g.parse().unwrap(); }
        if let Ok(g) = std::env::var("GD") { model.trunk.groove = g.parse().unwrap(); }
        if let Ok(g) = std::env::var("PW") { model.trunk.paraspinal_width = g.parse().unwrap(); }
        let dots: Vec<_> = back_dots(&model, spacing).into_iter().filter(|d| std::env::var("NOARMS").is_err() || d.hit.part == Part::Back).collect();
        let mut noise = Noise::issue();
        if let Ok(f) = std::env::var("NOISE") { let f: f64 = f.parse().unwrap(); noise.depth *= f; noise.lateral *= f; noise.common_shift *= f; noise.common_tilt *= f; }
        let axes = Axes::camera();
        let results: Vec<_> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..2).map(|t| { let dots = &dots; let model = &model; s.spawn(move || {
                let mut out = vec![];
                for k in (0..draws).filter(|k| k % 2 == t) {
                    let mut r = rng(k + 100);
                    let delta = common_draw(&noise, &mut r);
                    let f = frame(dots, &noise, &delta, &mut r);
                    let mut o = Options::standing(); o.smoothing = smoothing;
                    let a = match analyse(&[f], &o) { Ok(a) => a, Err(e) => { eprintln!("{} draw {k}: {e}", model.deformity.name); continue } };
                    let mut e = vec![];
                    for l in &a.levels {
                        let (tx, _) = model.symmetry_point(&axes, l.y).unwrap();
                        let tr = model.rotation(&axes, l.y).unwrap().to_degrees();
                        e.push((l.y, l.symmetry_x - tx, l.symmetry_x_sigma, l.rotation_deg - tr, l.rotation_sigma_deg));
                    }
                    if std::env::var("BAD").is_ok() && e.iter().any(|e| e.1.abs() > std::env::var("BAD").unwrap().parse::<f64>().unwrap()) { for x in &e { eprintln!("  draw {k} y {:.0} ex {:.2} er {:.2}", x.0, x.1, x.3); } }
                    let tmax = a.levels.iter().map(|l| model.rotation(&axes, l.y).unwrap().to_degrees()).max_by(|a, b| a.abs().total_cmp(&b.abs())).unwrap();
                    if std::env::var("DRAWS").is_ok() { eprintln!("draw {k} rotmax {:.3} x10 {:.3} pts {}", a.rotation_max_deg, a.levels[10].symmetry_x, a.points); }
                    out.push((e, a.rotation_max_deg - tmax, a.rotation_max_deg_sigma));
                }
                out
            })}).collect();
            hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
        });
        let all: Vec<_> = results.iter().flat_map(|r| r.0.iter()).collect();
        let n = all.len() as f64;
        let rms = |f: &dyn Fn(&(f64, f64, f64, f64, f64)) -> f64| (all.iter().map(|e| f(e).powi(2)).sum::<f64>() / n).sqrt();
        let mean = |f: &dyn Fn(&(f64, f64, f64, f64, f64)) -> f64| all.iter().map(|e| f(e)).sum::<f64>() / n;
        // bias per level: mean over draws at the same y
        let mut ys: Vec<f64> = all.iter().map(|e| (e.0 / 10.0).round()).collect(); ys.sort_by(f64::total_cmp); ys.dedup();
        let mut bx = 0.0; let mut br = 0.0;
        for y in &ys { let es: Vec<_> = all.iter().filter(|e| (e.0 / 10.0).round() == *y).collect(); let m = es.len() as f64;
            bx += (es.iter().map(|e| e.1).sum::<f64>()/m).powi(2); br += (es.iter().map(|e| e.3).sum::<f64>()/m).powi(2); }
        let nl = ys.len() as f64;
        let zmax = (results.iter().map(|r| (r.1/r.2).powi(2)).sum::<f64>() / results.len() as f64).sqrt();
        let emax = (results.iter().map(|r| r.1.powi(2)).sum::<f64>() / results.len() as f64).sqrt();
        println!("{:9} x rms {:.2} bias {:.2} sigma {:.2} z {:.2} | rot rms {:.3} bias {:.3} sigma {:.3} z {:.2} | rotmax err {:.3} z {:.2} mean x {:.2} rot {:.3}",
            d.name, rms(&|e| e.1), (bx/nl).sqrt(), mean(&|e| e.2), rms(&|e| e.1/e.2), rms(&|e| e.3), (br/nl).sqrt(), mean(&|e| e.4), rms(&|e| e.3/e.4), emax, zmax, mean(&|e| e.1), mean(&|e| e.3));
    }
}
