//! Rows moved by index (`ops::gather_rows`, `ops::scatter_rows`) against
//! the CPU reference on random rows, widths and index lists: every 32-bit
//! pattern (NaN payloads included) must arrive unchanged, and nothing
//! outside the listed rows may change.

use rand::seq::SliceRandom;
use rand::Rng;

use super::*;
use crate::ops::{gather_rows, scatter_rows};
use crate::testing::rng;
use latentam_reference::rows;

#[test]
fn rows_gathered_and_scattered_match_the_reference_bit_for_bit() {
    with_context(|ctx| {
        let mut r = rng("rows_gathered_and_scattered_match_the_reference_bit_for_bit");
        // Widths of the window's fields (1, 3, 4, 32) and one that is
        // none of them; counts around a workgroup's edge and one large.
        for width in [1u32, 3, 4, 32, 33] {
            for count in [0u32, 1, 255, 256, 257, r.random_range(1_000..40_000)] {
                let rows_in_data = count.max(1) + r.random_range(0..500);
                let data: Vec<u32> = (0..rows_in_data * width).map(|_| r.random()).collect();
                // Gather: any rows, repeats allowed.
                let picks: Vec<u32> = (0..count)
                    .map(|_| r.random_range(0..rows_in_data))
                    .collect();
                // Scatter: distinct rows.
                let mut all: Vec<u32> = (0..rows_in_data).collect();
                all.shuffle(&mut r);
                let targets = &all[..count as usize];
                let incoming: Vec<u32> = (0..count * width).map(|_| r.random()).collect();

                let data_gpu = ctx.upload_new("rows/data", &data).unwrap();
                let target_gpu = ctx.upload_new("rows/scattered", &data).unwrap();
                let words = (count * width).max(1) as usize;
                let out = ctx.upload_new("rows/out", &vec![0u32; words]).unwrap();
                let pick_gpu = ctx
                    .upload_new("rows/picks", &[&picks[..], &[0]].concat())
                    .unwrap();
                let target_index = ctx
                    .upload_new("rows/targets", &[targets, &[0]].concat())
                    .unwrap();
                let incoming_gpu = ctx
                    .upload_new("rows/incoming", &[&incoming[..], &[0]].concat())
                    .unwrap();
                let mut rec = ctx.recorder().unwrap();
                gather_rows(&mut rec, &data_gpu, &out, &pick_gpu, count, width).unwrap();
                scatter_rows(
                    &mut rec,
                    &target_gpu,
                    &incoming_gpu,
                    &target_index,
                    count,
                    width,
                )
                .unwrap();
                rec.submit().unwrap().wait().unwrap();

                let gathered: Vec<u32> = ctx.download(&out).unwrap();
                let want = rows::gather(&data, width as usize, &picks);
                assert!(
                    gathered[..want.len()] == want[..],
                    "gather: width {width}, count {count}"
                );
                let mut scattered = data.clone();
                rows::scatter(&mut scattered, width as usize, targets, &incoming);
                let got: Vec<u32> = ctx.download(&target_gpu).unwrap();
                assert!(
                    got[..scattered.len()] == scattered[..],
                    "scatter: width {width}, count {count}"
                );
            }
        }
    });
}

/// A staging buffer or an index list too small for the rows asked for is
/// refused before anything is recorded.
#[test]
fn rows_that_do_not_fit_their_buffers_are_refused() {
    with_context(|ctx| {
        let data = ctx.upload_new("rows/data", &[0u32; 64]).unwrap();
        let staging = ctx.upload_new("rows/staging", &[0u32; 8]).unwrap();
        let index = ctx.upload_new("rows/index", &[0u32; 2]).unwrap();
        let mut rec = ctx.recorder().unwrap();
        for (count, width) in [(3, 4), (2, 5)] {
            let e = gather_rows(&mut rec, &data, &staging, &index, count, width).unwrap_err();
            assert!(matches!(e, Error::BadInput { .. }), "{e}");
        }
        gather_rows(&mut rec, &data, &staging, &index, 2, 4).unwrap();
        rec.submit().unwrap().wait().unwrap();
    });
}
