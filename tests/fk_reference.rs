//! `marionette fk` against a second, independent forward kinematics: its own small ASF/AMC
//! reader, f64 throughout, 4×4 homogeneous matrices chained in each bone's local frame with
//! `R_asf = C_parentᵀ·C_bone` (help note eq. 1–5), instead of the library's global-frame
//! formulation. Every frame of both bundled clips must agree to 1e-4 file units.

mod common;

use std::collections::HashMap;

type M4 = [[f64; 4]; 4];

fn ident() -> M4 {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

fn mul(a: &M4, b: &M4) -> M4 {
    let mut m = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            m[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

fn rot(axis: char, deg: f64) -> M4 {
    let (s, c) = deg.to_radians().sin_cos();
    let mut m = ident();
    let (i, j) = match axis {
        'x' => (1, 2),
        'y' => (2, 0),
        _ => (0, 1),
    };
    m[i][i] = c;
    m[j][j] = c;
    m[i][j] = -s;
    m[j][i] = s;
    m
}

fn trans(v: [f64; 3]) -> M4 {
    let mut m = ident();
    for k in 0..3 {
        m[k][3] = v[k];
    }
    m
}

fn transpose(a: &M4) -> M4 {
    let mut m = ident();
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = a[j][i];
        }
    }
    m
}

fn apply(m: &M4, v: [f64; 3]) -> [f64; 3] {
    let mut r = [0.0; 3];
    for i in 0..3 {
        r[i] = m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2] + m[i][3];
    }
    r
}

#[derive(Default, Clone)]
struct RefBone {
    dir: [f64; 3],
    len: f64,
    axis: [f64; 3],
    dofs: Vec<char>,
    parent: String,
}

struct RefSkeleton {
    bones: HashMap<String, RefBone>,
    order: Vec<String>,
}

fn nums(parts: &[&str]) -> Vec<f64> {
    parts.iter().map(|p| p.parse::<f64>().unwrap()).collect()
}

/// A plain reader for the CMU files: XYZ axes, rotation DOFs, root order TX TY TZ RX RY RZ.
fn read_asf(text: &str) -> RefSkeleton {
    let mut bones = HashMap::new();
    let mut order = Vec::new();
    let mut section = "";
    let mut cur: Option<(String, RefBone)> = None;
    for line in text.lines() {
        let parts: Vec<&str> = line.split_whitespace().collect();
        if parts.is_empty() || parts[0].starts_with('#') {
            continue;
        }
        if parts[0].starts_with(':') {
            section = if parts[0] == ":bonedata" {
                "bones"
            } else if parts[0] == ":hierarchy" {
                "tree"
            } else if parts[0] == ":root" {
                "root"
            } else {
                ""
            };
            continue;
        }
        match section {
            "root" if parts[0] == "order" => assert_eq!(parts[1..].join(" "), "TX TY TZ RX RY RZ"),
            "bones" => match parts[0] {
                "begin" => cur = Some((String::new(), RefBone::default())),
                "name" => cur.as_mut().unwrap().0 = parts[1].to_string(),
                "direction" => {
                    let v = nums(&parts[1..4]);
                    cur.as_mut().unwrap().1.dir = [v[0], v[1], v[2]];
                }
                "length" => cur.as_mut().unwrap().1.len = parts[1].parse().unwrap(),
                "axis" => {
                    assert_eq!(parts[4], "XYZ");
                    let v = nums(&parts[1..4]);
                    cur.as_mut().unwrap().1.axis = [v[0], v[1], v[2]];
                }
                "dof" => {
                    cur.as_mut().unwrap().1.dofs =
                        parts[1..].iter().map(|d| d.chars().nth(1).unwrap()).collect()
                }
                "end" => {
                    let (n, b) = cur.take().unwrap();
                    order.push(n.clone());
                    bones.insert(n, b);
                }
                _ => {}
            },
            "tree" => {
                if parts[0] == "begin" || parts[0] == "end" {
                    continue;
                }
                for child in &parts[1..] {
                    bones.get_mut(*child).unwrap().parent = parts[0].to_string();
                }
            }
            _ => {}
        }
    }
    RefSkeleton { bones, order }
}

fn read_amc(text: &str) -> Vec<HashMap<String, Vec<f64>>> {
    let mut frames = Vec::new();
    for line in text.lines() {
        let parts: Vec<&str> = line.split_whitespace().collect();
        if parts.is_empty() || parts[0].starts_with('#') || parts[0].starts_with(':') {
            continue;
        }
        if parts.len() == 1 && parts[0].parse::<u32>().is_ok() {
            frames.push(HashMap::new());
            continue;
        }
        frames
            .last_mut()
            .unwrap()
            .insert(parts[0].to_string(), nums(&parts[1..]));
    }
    frames
}

/// `C = Rz(c)·Ry(b)·Rx(a)`, eq. (3).
fn axis_matrix(a: [f64; 3]) -> M4 {
    mul(&mul(&rot('z', a[2]), &rot('y', a[1])), &rot('x', a[0]))
}

/// Tip of every bone (the root: its position), eq. (1)–(5) in each bone's local frame.
fn reference_fk(s: &RefSkeleton, frame: &HashMap<String, Vec<f64>>) -> HashMap<String, [f64; 3]> {
    let r = &frame["root"];
    let root = mul(
        &trans([r[0], r[1], r[2]]),
        &mul(&mul(&rot('z', r[5]), &rot('y', r[4])), &rot('x', r[3])),
    );
    let mut global: HashMap<String, M4> = HashMap::new();
    let mut tips = HashMap::new();
    global.insert("root".into(), root);
    tips.insert("root".to_string(), [r[0], r[1], r[2]]);
    let mut pending: Vec<String> = s.order.clone();
    while !pending.is_empty() {
        pending.retain(|name| {
            let b = &s.bones[name];
            let Some(parent_g) = global.get(&b.parent).copied() else {
                return true;
            };
            let c = axis_matrix(b.axis);
            let (parent_c, offset) = if b.parent == "root" {
                (ident(), [0.0; 3])
            } else {
                let p = &s.bones[&b.parent];
                let pc = axis_matrix(p.axis);
                let local = apply(&transpose(&pc), p.dir); // eq. (5)
                (pc, [local[0] * p.len, local[1] * p.len, local[2] * p.len])
            };
            let r_asf = mul(&transpose(&parent_c), &c); // eq. (4)
            let mut r_amc = ident();
            if let Some(values) = frame.get(name) {
                for (d, v) in b.dofs.iter().zip(values) {
                    r_amc = mul(&rot(*d, *v), &r_amc);
                }
            }
            let g = mul(&mul(&mul(&parent_g, &trans(offset)), &r_asf), &r_amc); // eq. (1)
            let local_dir = apply(&transpose(&c), b.dir);
            let tip = apply(
                &g,
                [local_dir[0] * b.len, local_dir[1] * b.len, local_dir[2] * b.len],
            ); // eq. (2)
            global.insert(name.clone(), g);
            tips.insert(name.clone(), tip);
            false
        });
    }
    tips
}

fn check_clip(asf: &str, amc: &str) -> (usize, f64) {
    let skel = read_asf(&common::read(asf));
    let frames = read_amc(&common::read(amc));
    let out = common::bin()
        .args(["fk"])
        .arg(common::data(asf))
        .arg(common::data(amc))
        .output()
        .expect("run marionette fk");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let csv = String::from_utf8(out.stdout).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("frame,bone,x,y,z"));
    let mut worst = 0.0f64;
    let mut rows = 0;
    let mut expected_cache: Option<(usize, HashMap<String, [f64; 3]>)> = None;
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f.len(), 5, "{line}");
        for v in &f[2..] {
            let decimals = v.split('.').nth(1).map_or(0, str::len);
            assert!(decimals >= 6, "at least 6 decimals: {line}");
        }
        let frame: usize = f[0].parse().unwrap();
        if expected_cache.as_ref().map(|c| c.0) != Some(frame) {
            expected_cache = Some((frame, reference_fk(&skel, &frames[frame - 1])));
        }
        let want = expected_cache.as_ref().unwrap().1[f[1]];
        let got = nums(&f[2..5]);
        for k in 0..3 {
            worst = worst.max((got[k] - want[k]).abs());
        }
        rows += 1;
    }
    assert_eq!(
        rows,
        frames.len() * (skel.order.len() + 1),
        "one row per frame and bone"
    );
    (rows, worst)
}

#[test]
fn fk_matches_independent_reference_on_walk() {
    let (rows, worst) = check_clip("16.asf", "16_15.amc");
    assert_eq!(rows, 471 * 31);
    assert!(worst < 1e-4, "worst difference {worst} file units");
    eprintln!("16_15: {rows} positions, worst difference {worst:.2e} units");
}

#[test]
fn fk_matches_independent_reference_on_playground() {
    let (rows, worst) = check_clip("01.asf", "01_01.amc");
    assert_eq!(rows, 2751 * 31);
    assert!(worst < 1e-4, "worst difference {worst} file units");
    eprintln!("01_01: {rows} positions, worst difference {worst:.2e} units");
}
