//! PLY round trips, other tools' files, and damaged files.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::format::*;
use super::read::*;
use super::write::*;
use crate::map::Gaussian;
use crate::splat::QUERY_DIM;
use bytemuck::Zeroable;

/// Whether a partial file of `path` (`<path>.*.partial`) is left beside it.
fn partial_left(path: &std::path::Path) -> bool {
    let name = path.file_name().unwrap().to_string_lossy().into_owned();
    std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .any(|n| n.starts_with(&format!("{name}.")) && n.ends_with(".partial"))
}
use latentam_base::files::testing::TempDir;
use latentam_base::Error;
use std::path::Path;

fn random_gaussians(n: usize, seed: u64) -> Vec<Gaussian> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut g = Gaussian::zeroed();
            g.mean = std::array::from_fn(|_| rng.random_range(-10.0..10.0));
            g.log_scale = std::array::from_fn(|_| rng.random_range(-6.0..0.0));
            g.quat = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            g.color = std::array::from_fn(|_| rng.random_range(0.0..1.0));
            g.opacity_logit = rng.random_range(-5.0..5.0);
            g.query = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            g
        })
        .collect()
}

fn assert_same(a: &Gaussian, b: &Gaussian) {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.mean), bits(&b.mean));
    assert_eq!(bits(&a.log_scale), bits(&b.log_scale));
    assert_eq!(bits(&unit_quat(a.quat)), bits(&b.quat));
    assert_eq!(a.opacity_logit.to_bits(), b.opacity_logit.to_bits());
    assert_eq!(bits(&a.query), bits(&b.query));
    for (x, y) in a.color.iter().zip(&b.color) {
        assert!((x - y).abs() <= 1e-6, "colour {x} vs {y}");
    }
}

/// A header followed by `body`, written by hand.
fn write_raw(path: &Path, header: &str, body: &[u8]) {
    let mut bytes = header.as_bytes().to_vec();
    bytes.extend_from_slice(body);
    std::fs::write(path, bytes).unwrap();
}

fn expect_error(path: &Path, needle: &str) {
    match read_ply(path) {
        Err(Error::Damaged { path: p, reason }) => {
            assert_eq!(p, path);
            assert!(
                reason.contains(needle),
                "{reason:?} should mention {needle:?}"
            );
        }
        other => panic!("expected a format error mentioning {needle:?}, got {other:?}"),
    }
}

#[test]
fn round_trip_is_bit_exact_except_colour() {
    let dir = TempDir::new("ply");
    let path = dir.path().join("map.ply");
    // More than one chunk, and not a multiple of it.
    let gaussians = random_gaussians(ROWS_PER_CHUNK + 123, 1);
    let relevance: Vec<f32> = (0..gaussians.len()).map(|i| i as f32 * 0.25).collect();
    write_ply(&path, &gaussians, &[("relevance", &relevance)]).unwrap();
    assert!(!partial_left(&path));

    let map = read_ply(&path).unwrap();
    assert_eq!(map.gaussians.len(), gaussians.len());
    for (a, b) in gaussians.iter().zip(&map.gaussians) {
        assert_same(a, b);
    }
    assert_eq!(map.extra, vec![("relevance".to_owned(), relevance)]);

    // Overwriting replaces the file.
    write_ply(&path, &gaussians[..3], &[]).unwrap();
    let map = read_ply(&path).unwrap();
    assert_eq!(map.gaussians.len(), 3);
    assert!(map.extra.is_empty());
}

#[test]
fn empty_map_round_trips() {
    let dir = TempDir::new("ply");
    let path = dir.path().join("empty.ply");
    write_ply(&path, &[], &[("score", &[])]).unwrap();
    let map = read_ply(&path).unwrap();
    assert!(map.gaussians.is_empty());
    assert_eq!(map.extra, vec![("score".to_owned(), vec![])]);
}

#[test]
fn header_is_exact() {
    let dir = TempDir::new("ply");
    let path = dir.path().join("one.ply");
    let mut g = Gaussian::zeroed();
    g.color = [0.5, 0.5 + SH_C0 as f32, 0.5];
    g.quat = [1.0, 0.0, 0.0, 0.0];
    write_ply(&path, &[g], &[("relevance", &[0.75])]).unwrap();
    let bytes = std::fs::read(&path).unwrap();

    let mut expected = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by latentam {}\n\
         comment latent_dim 32\nelement vertex 1\n",
        env!("CARGO_PKG_VERSION")
    );
    for name in [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
        "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
    ] {
        expected += &format!("property float {name}\n");
    }
    for i in 0..32 {
        expected += &format!("property float latent_{i}\n");
    }
    expected += "property float relevance\nend_header\n";
    assert_eq!(
        std::str::from_utf8(&bytes[..expected.len()]).unwrap(),
        expected
    );

    let body: &[u8] = &bytes[expected.len()..];
    assert_eq!(body.len(), (STANDARD_FLOATS + 1) * 4);
    let floats: Vec<f32> = body
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(floats[6], 0.0, "grey is f_dc 0");
    assert!((floats[7] - 1.0).abs() < 1e-6, "0.5 + C0 is f_dc 1");
    assert_eq!(floats[13..17], [1.0, 0.0, 0.0, 0.0], "rot is w x y z");
    assert_eq!(floats[STANDARD_FLOATS], 0.75);
}

#[test]
fn rotations_are_written_unit_length_and_latents_only_when_asked() {
    let dir = TempDir::new("ply");
    let mut gs = random_gaussians(300, 9);
    gs[0].quat = [0.0; 4];
    gs[1].quat = [f32::NAN, 0.0, 0.0, 1.0];
    gs[2].quat = [3.0, 0.0, 4.0, 0.0];
    let path = dir.path().join("map.ply");
    write_ply(&path, &gs, &[]).unwrap();
    let back = read_ply(&path).unwrap().gaussians;
    for (g, b) in gs.iter().zip(&back) {
        let n: f64 = b
            .quat
            .iter()
            .map(|&v| f64::from(v).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((n - 1.0).abs() < 1e-6, "{:?} -> {:?}", g.quat, b.quat);
    }
    assert_eq!(back[0].quat, [1.0, 0.0, 0.0, 0.0]);
    assert_eq!(back[1].quat, [1.0, 0.0, 0.0, 0.0]);
    assert_eq!(back[2].quat, [0.6, 0.0, 0.8, 0.0]);
    // The same rotation: a direction rotated by either agrees.
    let rot =
        |q: [f32; 4]| glam::Quat::from_xyzw(q[1], q[2], q[3], q[0]).normalize() * glam::Vec3::X;
    for (g, b) in gs.iter().zip(&back).skip(3) {
        assert!((rot(g.quat) - rot(b.quat)).length() < 1e-5);
    }

    // Without latents: no latent_* property, queries read back as 0,
    // everything else as before.
    let path = dir.path().join("geometry.ply");
    write_ply_without_latents(&path, &gs, &[("score", &vec![0.5; 300])]).unwrap();
    let text = std::fs::read(&path).unwrap();
    let header = String::from_utf8_lossy(&text[..2048]);
    assert!(!header.contains("latent_"), "{header}");
    let map = read_ply(&path).unwrap();
    assert_eq!(map.extra[0].1, vec![0.5; 300]);
    for (g, b) in gs.iter().zip(&map.gaussians).skip(3) {
        assert_eq!(b.query, [0.0; QUERY_DIM]);
        assert_eq!((g.mean, g.log_scale), (b.mean, b.log_scale));
    }
}

#[test]
fn reads_by_name_in_any_order_and_type() {
    let dir = TempDir::new("ply");
    let path = dir.path().join("shuffled.ply");
    let header = "ply\r\nformat binary_little_endian 1.0\r\ncomment by hand\r\n\
        obj_info nothing\r\nelement vertex 2\r\n\
        property float rot_3\r\nproperty float32 opacity\r\nproperty double x\r\n\
        property float confidence\r\nproperty float f_dc_2\r\nproperty float y\r\n\
        property float scale_2\r\nproperty float rot_0\r\nproperty float f_dc_0\r\n\
        property float scale_0\r\nproperty float z\r\nproperty float rot_1\r\n\
        property uchar label\r\nproperty float f_dc_1\r\nproperty float scale_1\r\n\
        property float rot_2\r\nend_header\r\n";
    let mut body = Vec::new();
    for v in 0..2u8 {
        let k = f32::from(v) + 1.0;
        let f = |body: &mut Vec<u8>, x: f32| body.extend_from_slice(&x.to_le_bytes());
        f(&mut body, 0.4 * k); // rot_3
        f(&mut body, -2.0 * k); // opacity
        body.extend_from_slice(&(1.5f64 * f64::from(k)).to_le_bytes()); // x
        f(&mut body, 0.9 * k); // confidence
        f(&mut body, 0.0); // f_dc_2
        f(&mut body, 2.5 * k); // y
        f(&mut body, -3.0 * k); // scale_2
        f(&mut body, 0.1 * k); // rot_0
        f(&mut body, 1.0); // f_dc_0
        f(&mut body, -k); // scale_0
        f(&mut body, 3.5 * k); // z
        f(&mut body, 0.2 * k); // rot_1
        body.push(7 + v); // label
        f(&mut body, -1.0); // f_dc_1
        f(&mut body, -2.0 * k); // scale_1
        f(&mut body, 0.3 * k); // rot_2
    }
    write_raw(&path, header, &body);

    let map = read_ply(&path).unwrap();
    assert_eq!(map.gaussians.len(), 2);
    for (v, g) in map.gaussians.iter().enumerate() {
        let k = v as f32 + 1.0;
        assert_eq!(g.mean, [1.5 * k, 2.5 * k, 3.5 * k]);
        assert_eq!(g.log_scale, [-k, -2.0 * k, -3.0 * k]);
        assert_eq!(g.quat, [0.1 * k, 0.2 * k, 0.3 * k, 0.4 * k]);
        assert_eq!(g.opacity_logit, -2.0 * k);
        let c0 = SH_C0 as f32;
        for (c, want) in g.color.iter().zip([0.5 + c0, 0.5 - c0, 0.5]) {
            assert!((c - want).abs() < 1e-6);
        }
        assert_eq!(g.query, [0.0; QUERY_DIM], "no latents: zero query");
    }
    assert_eq!(
        map.extra,
        vec![
            ("confidence".to_owned(), vec![0.9, 1.8]),
            ("label".to_owned(), vec![7.0, 8.0]),
        ]
    );
}

#[test]
fn bad_files_are_errors() {
    let dir = TempDir::new("ply");
    let good = dir.path().join("good.ply");
    write_ply(&good, &random_gaussians(3, 2), &[]).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let header_len = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..header_len]).unwrap();
    let body = &bytes[header_len..];
    let path = dir.path().join("bad.ply");

    write_raw(&path, header, &body[..body.len() - 1]);
    expect_error(&path, "truncated");

    write_raw(&path, header, &[body, &[0]].concat());
    expect_error(&path, "1 bytes after");

    write_raw(
        &path,
        &header.replace("vertex 3\n", "vertex 1000000000000\n"),
        body,
    );
    expect_error(&path, "truncated");

    write_raw(
        &path,
        &header.replace("vertex 3\n", "vertex 18446744073709551615\n"),
        body,
    );
    expect_error(&path, "impossibly large");

    write_raw(&path, &header.replace("vertex 3", "vertex -3"), body);
    expect_error(&path, "bad vertex count");

    write_raw(
        &path,
        &header.replace("binary_little_endian", "ascii"),
        body,
    );
    expect_error(&path, "only binary_little_endian 1.0");

    write_raw(
        &path,
        &header.replace("binary_little_endian", "binary_big_endian"),
        body,
    );
    expect_error(&path, "not supported");

    write_raw(&path, &header.replace("endian 1.0", "endian 2.0"), body);
    expect_error(&path, "unknown format line");

    write_raw(&path, &header.replace("property float opacity\n", ""), body);
    expect_error(&path, "missing vertex properties: opacity");

    write_raw(&path, &header.replace("float rot_1", "float x"), body);
    expect_error(&path, "appears twice");

    write_raw(&path, &header.replace("latent_31", "latent_32"), body);
    expect_error(&path, "latent_0..latent_31");

    write_raw(
        &path,
        &header.replace("property float latent_31\n", ""),
        body,
    );
    expect_error(&path, "31 latent properties");

    write_raw(
        &path,
        &header.replace("float rot_1", "float64x rot_1"),
        body,
    );
    expect_error(&path, "unknown property type");

    write_raw(
        &path,
        &header.replace("float rot_1", "list uchar int rot_1"),
        body,
    );
    expect_error(&path, "list properties");

    let face = header.replace(
        "end_header",
        "element face 0\nproperty list uchar int i\nend_header",
    );
    write_raw(&path, &face, body);
    expect_error(&path, "element `face`");

    write_raw(&path, &header.replace("end_header\n", ""), &[]);
    expect_error(&path, "no end_header before the end");

    write_raw(&path, &header.replace("end_header\n", ""), body);
    expect_error(&path, "");

    write_raw(&path, &header.replace("end_header\n", "end_header"), &[]);
    expect_error(&path, "no end_header");

    write_raw(&path, &header.replace("comment", "remark"), body);
    expect_error(&path, "unknown line `remark");

    write_raw(&path, "", &[]);
    expect_error(&path, "empty file");

    write_raw(&path, "PK\u{3}\u{4}", &[0xff; 64]);
    expect_error(&path, "magic");

    write_raw(&path, "ply\n", &[0xff, 0xfe, b'\n']);
    expect_error(&path, "not text");

    write_raw(&path, "ply\n", &[b'x'; 1 << 21]);
    expect_error(&path, "no end_header in the first");

    write_raw(&path, "ply\nend_header\n", &[]);
    expect_error(&path, "no format line");

    write_raw(
        &path,
        "ply\nformat binary_little_endian 1.0\nend_header\n",
        &[],
    );
    expect_error(&path, "no vertex element");

    write_raw(
        &path,
        "ply\nformat binary_little_endian 1.0\nproperty float x\n",
        &[],
    );
    expect_error(&path, "property outside an element");

    assert!(matches!(
        read_ply(&dir.path().join("missing.ply")),
        Err(Error::Io { .. })
    ));
}

#[test]
fn bad_extras_are_rejected_before_writing() {
    let dir = TempDir::new("ply");
    let path = dir.path().join("map.ply");
    let gaussians = random_gaussians(2, 3);
    let two = [1.0f32, 2.0];
    for extra in [
        vec![("relevance", &two[..1])],
        vec![("relevance", &two[..]), ("relevance", &two[..])],
        vec![("opacity", &two[..])],
        vec![("latent_3", &two[..])],
        vec![("latent_32", &two[..])],
        vec![("nx", &two[..])],
        vec![("has space", &two[..])],
        vec![("", &two[..])],
    ] {
        let result = write_ply(&path, &gaussians, &extra);
        assert!(matches!(result, Err(Error::BadInput { .. })), "{extra:?}");
    }
    assert!(!path.exists() && !partial_left(&path));
}

#[test]
fn failed_write_leaves_no_partial_file() {
    let dir = TempDir::new("ply");
    // The target is a directory, so the rename fails after the partial
    // file was written.
    let path = dir.path().join("taken");
    std::fs::create_dir(&path).unwrap();
    std::fs::write(path.join("keep"), b"x").unwrap();
    assert!(matches!(
        write_ply(&path, &random_gaussians(1, 4), &[]),
        Err(Error::Io { .. })
    ));
    assert!(!partial_left(&path));
    // Nor does a write into a missing directory leave anything behind.
    let nowhere = dir.path().join("no/such/dir/map.ply");
    assert!(matches!(
        write_ply(&nowhere, &[], &[]),
        Err(Error::Io { .. })
    ));
}

#[test]
fn a_streamed_map_writes_the_same_file_and_a_wrong_count_writes_none() {
    let dir = TempDir::new("ply-streamed");
    let gaussians = random_gaussians(3000, 17);
    let whole = dir.path().join("whole.ply");
    write_map_ply(&whole, &gaussians, true).unwrap();
    let streamed = dir.path().join("streamed.ply");
    write_map_ply_streamed(&streamed, gaussians.len(), true, |put| {
        gaussians.chunks(333).try_for_each(put)
    })
    .unwrap();
    assert_eq!(
        std::fs::read(&whole).unwrap(),
        std::fs::read(&streamed).unwrap()
    );
    for count in [2999, 3001] {
        let e = write_map_ply_streamed(&streamed, count, true, |put| put(&gaussians))
            .unwrap_err()
            .to_string();
        assert!(e.contains("3000 Gaussians written"), "{e}");
        assert_eq!(
            std::fs::read(&whole).unwrap(),
            std::fs::read(&streamed).unwrap()
        );
        assert!(!partial_left(&streamed));
    }
}
