#[path = "../tests/it/back_sim.rs"]
#[allow(dead_code)]
mod back_sim;
use back_sim::*;
use deltaz_host::simulate::back::{Axes, BackModel, Deformity, Pose};
use deltaz_surface::{analyse, Options};
use nalgebra::Vector3;

fn main() {
    let frames: usize = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(3);
    let draws: u64 = std::env::args().nth(2).map(|s| s.parse().unwrap()).unwrap_or(10);
    let axes = Axes::camera();
    for d in [Deformity::thoracic(), Deformity::double()] {
        let base = BackModel::standing(d.clone());
        let poses = [Pose::default(), Pose { rotation: Vector3::new(0.3, -1.0, 0.5).map(f64::to_radians), translation: Vector3::new(3.0, -2.0, 4.0) },
            Pose { rotation: Vector3::new(-0.5, 0.8, -0.6).map(f64::to_radians), translation: Vector3::new(-2.5, 3.0, -3.0) },
            Pose { rotation: Vector3::new(0.6, 0.5, 0.9).map(f64::to_radians), translation: Vector3::new(1.0, 4.0, 2.0) }];
        let models: Vec<_> = poses.iter().take(frames).map(|p| base.with_pose(*p)).collect();
        let dots: Vec<_> = models.iter().map(|m| back_dots(m, 20.0)).collect();
        let noise = Noise::issue();
        let (mut ex, mut zx, mut er, mut zr, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut sx = 0.0; let mut sr = 0.0;
        for k in 0..draws {
            let mut r = rng(k + 500);
            let delta = common_draw(&noise, &mut r);
            let fs: Vec<_> = dots.iter().map(|d| frame(d, &noise, &delta, &mut r)).collect();
            let a = match analyse(&fs, &Options::standing()) { Ok(a) => a, Err(e) => { println!("{e}"); continue } };
            if k == 0 { for s in &a.sway { println!("sway {:?}", s); } }
            for l in &a.levels {
                let Some((tx, _)) = models[0].symmetry_point(&axes, l.y) else { continue };
                let tr = models[0].rotation(&axes, l.y).unwrap().to_degrees();
                ex += (l.symmetry_x - tx).powi(2); zx += ((l.symmetry_x - tx) / l.symmetry_x_sigma).powi(2);
                er += (l.rotation_deg - tr).powi(2); zr += ((l.rotation_deg - tr) / l.rotation_sigma_deg).powi(2);
                sx += l.symmetry_x_sigma; sr += l.rotation_sigma_deg; n += 1.0;
            }
        }
        println!("{:9} frames {} x rms {:.2} z {:.2} sigma {:.2} | rot rms {:.3} z {:.2} sigma {:.3}", d.name, frames, (ex/n).sqrt(), (zx/n).sqrt(), sx/n, (er/n).sqrt(), (zr/n).sqrt(), sr/n);
    }
}
