//! Rows moved by index (`ops::gather_rows`, `ops::scatter_rows`,
//! `ops::move_rows`) against the CPU reference on random rows, widths,
//! index lists and offsets: every 32-bit pattern (NaN payloads included)
//! must arrive unchanged, and nothing outside the listed rows may change.

use rand::seq::SliceRandom;
use rand::Rng;

use super::*;
use crate::ops::{gather_rows, move_rows, scatter_rows, Packed, RowList};
use crate::testing::rng;
use latentam_reference::rows;

#[test]
fn rows_gathered_scattered_and_moved_match_the_reference_bit_for_bit() {
    with_context(|ctx| {
        let mut r = rng("rows_gathered_scattered_and_moved_match_the_reference_bit_for_bit");
        // Widths of the window's fields (1, 3, 4, 32) and one that is
        // none of them; counts around a workgroup's edge and one large.
        for width in [1u32, 3, 4, 32, 33] {
            for count in [0u32, 1, 255, 256, 257, r.random_range(1_000..40_000)] {
                let rows_in_data = 2 * count.max(1) + r.random_range(0..500);
                let data: Vec<u32> = (0..rows_in_data * width).map(|_| r.random()).collect();
                // Lists start part-way into their index buffer, and rows
                // part-way into the staging buffer, as the window's packed
                // outbox puts them.
                let list = r.random_range(0..100u32);
                let word = r.random_range(0..1000u64);
                let lead: Vec<u32> = (0..list).map(|_| r.random()).collect();
                // Gather: any rows, repeats allowed.
                let picks: Vec<u32> = (0..count)
                    .map(|_| r.random_range(0..rows_in_data))
                    .collect();
                // Scatter: distinct rows. Move: distinct sources and
                // destinations, no row both.
                let mut all: Vec<u32> = (0..rows_in_data).collect();
                all.shuffle(&mut r);
                let targets = &all[..count as usize];
                let sources = &all[count as usize..2 * count as usize];
                let incoming: Vec<u32> = (0..count * width).map(|_| r.random()).collect();

                let data_gpu = ctx.upload_new("rows/data", &data).unwrap();
                let target_gpu = ctx.upload_new("rows/scattered", &data).unwrap();
                let moved_gpu = ctx.upload_new("rows/moved", &data).unwrap();
                let words = word as usize + (count * width) as usize;
                let out = ctx.upload_new("rows/out", &vec![0u32; words]).unwrap();
                let pick_gpu = ctx
                    .upload_new("rows/picks", &[&lead[..], &picks, &[0]].concat())
                    .unwrap();
                let target_index = ctx
                    .upload_new("rows/targets", &[&lead[..], targets, &[0]].concat())
                    .unwrap();
                let move_index = ctx
                    .upload_new("rows/moves", &[&lead[..], sources, targets, &[0]].concat())
                    .unwrap();
                let padded: Vec<u32> = (0..word).map(|_| r.random()).collect();
                let incoming_gpu = ctx
                    .upload_new("rows/incoming", &[&padded[..], &incoming, &[0]].concat())
                    .unwrap();
                let at = |index| RowList {
                    index,
                    first: list,
                    count,
                };
                let mut rec = ctx.recorder().unwrap();
                let to_out = Packed { buffer: &out, word };
                gather_rows(&mut rec, &data_gpu, width, at(&pick_gpu), to_out).unwrap();
                let from_in = Packed {
                    buffer: &incoming_gpu,
                    word,
                };
                scatter_rows(&mut rec, &target_gpu, width, at(&target_index), from_in).unwrap();
                move_rows(&mut rec, &moved_gpu, width, at(&move_index)).unwrap();
                rec.submit().unwrap().wait().unwrap();

                let gathered: Vec<u32> = ctx.download(&out).unwrap();
                let want = rows::gather(&data, width as usize, &picks);
                assert!(
                    gathered[word as usize..] == want[..],
                    "gather: width {width}, count {count}"
                );
                assert!(
                    gathered[..word as usize].iter().all(|&w| w == 0),
                    "gather wrote before its first word"
                );
                let mut scattered = data.clone();
                rows::scatter(&mut scattered, width as usize, targets, &incoming);
                let got: Vec<u32> = ctx.download(&target_gpu).unwrap();
                assert!(
                    got[..scattered.len()] == scattered[..],
                    "scatter: width {width}, count {count}"
                );
                let mut moved = data.clone();
                rows::move_rows(&mut moved, width as usize, sources, targets);
                let got: Vec<u32> = ctx.download(&moved_gpu).unwrap();
                assert!(
                    got[..moved.len()] == moved[..],
                    "move: width {width}, count {count}"
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
        let index = ctx.upload_new("rows/index", &[0u32; 4]).unwrap();
        let list = |first, count| RowList {
            index: &index,
            first,
            count,
        };
        let packed = |word| Packed {
            buffer: &staging,
            word,
        };
        let mut rec = ctx.recorder().unwrap();
        // Too many rows or words, a list past its buffer, rows past the
        // staging buffer's end, moves whose destinations run off the list.
        for (first, count, width, word) in [(0, 3, 4, 0), (0, 2, 5, 0), (3, 2, 1, 0), (0, 2, 4, 1)]
        {
            let e =
                gather_rows(&mut rec, &data, width, list(first, count), packed(word)).unwrap_err();
            assert!(matches!(e, Error::BadInput { .. }), "{e}");
        }
        let e = move_rows(&mut rec, &data, 4, list(1, 2)).unwrap_err();
        assert!(matches!(e, Error::BadInput { .. }), "{e}");
        gather_rows(&mut rec, &data, 4, list(2, 2), packed(0)).unwrap();
        move_rows(&mut rec, &data, 4, list(0, 2)).unwrap();
        rec.submit().unwrap().wait().unwrap();
    });
}
