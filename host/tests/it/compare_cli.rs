//! `deltaz compare` end to end: Table 5 in, Table 6's parameters and Table 7's MSE row out as JSON;
//! a point missing from the reference is an error naming it.

use std::process::Command;

const TABLE5: [(&str, [f64; 3], [f64; 3]); 9] = [
    ("01", [43.161, 85.613, 216.417], [-1.280, 0.983, 16.417]),
    ("02", [310.371, 83.755, 216.126], [-3.646, 1.032, 16.126]),
    ("03", [602.154, 76.648, 214.399], [-5.750, 0.874, 14.399]),
    ("11", [38.361, 341.798, 216.116], [-1.556, -1.272, 16.116]),
    ("12", [302.043, 348.593, 215.657], [-3.782, -1.177, 15.657]),
    ("13", [589.534, 355.892, 215.842], [-5.957, -1.061, 15.842]),
    ("21", [31.696, 592.934, 216.478], [-1.676, -3.338, 16.478]),
    ("22", [295.196, 610.164, 215.883], [-3.901, -3.156, 15.883]),
    ("23", [581.149, 628.259, 213.808], [-5.737, -2.696, 13.808]),
];

fn write_files(dir: &std::path::Path, skip_reference: Option<&str>) {
    let mut a = String::from("point,X,Y,Z\n");
    let mut b = String::from("point,X,Y,Z,sigma\n");
    for (label, p, e) in TABLE5 {
        a += &format!("{label},{},{},{}\n", p[0], p[1], p[2]);
        if Some(label) != skip_reference {
            b += &format!(
                "{label},{},{},{},0.1\n",
                p[0] - e[0],
                p[1] - e[1],
                p[2] - e[2]
            );
        }
    }
    std::fs::write(dir.join("a.csv"), a).unwrap();
    std::fs::write(dir.join("b.csv"), b).unwrap();
}

fn run(dir: &std::path::Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["compare", "--reconstructed"])
        .arg(dir.join("a.csv"))
        .arg("--reference")
        .arg(dir.join("b.csv"))
        .arg("--json")
        .output()
        .unwrap()
}

#[test]
fn table5_to_table6_and_7_as_json() {
    let dir = tempfile::tempdir().unwrap();
    write_files(dir.path(), None);
    let out = run(dir.path());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let num = |k: &str| v[k].as_f64().unwrap();
    assert!((num("lambda") - 0.992386).abs() < 5e-7);
    assert!((num("phi") + 0.0029948).abs() < 5e-8);
    assert!((num("Zc") + 18.4310).abs() < 5e-5);
    let mse: Vec<f64> = v["mse"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    for (got, want) in mse.iter().zip([0.1415, 0.2068, 0.5595]) {
        assert!((got - want).abs() < 6e-4, "{mse:?}");
    }
    assert_eq!(v["transformed"].as_array().unwrap().len(), 9);
    assert_eq!(v["residuals"][5]["point"], "13");
    assert!((v["residuals"][5]["Z"].as_f64().unwrap() + 1.047).abs() < 0.0015);
}

#[test]
fn missing_reference_point_is_named() {
    let dir = tempfile::tempdir().unwrap();
    write_files(dir.path(), Some("12"));
    let out = run(dir.path());
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("point \"12\" is not in the reference"),
        "{err}"
    );
}
