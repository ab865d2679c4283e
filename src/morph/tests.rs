//! Unit tests of the threshold, component, hull and morphology tools.

use super::*;
use crate::raster::{Plane, Unspecified};

/// Parses a mask drawn with '#' (set) and '.' (unset), one string per row.
fn m(rows: &[&str]) -> Mask<Unspecified> {
    let h = rows.len();
    let w = rows[0].len();
    Mask::from_fn(w, h, |x, y| rows[y].as_bytes()[x] == b'#')
}

fn show(mask: &Mask<Unspecified>) -> Vec<String> {
    (0..mask.height())
        .map(|y| {
            (0..mask.width())
                .map(|x| if mask.get(x, y) { '#' } else { '.' })
                .collect()
        })
        .collect()
}

#[test]
fn otsu_splits_two_clusters_in_the_gap() {
    // Ten pixels at 0.1 and ten at 0.8: the classes are {0.1} and {0.8}; the threshold is
    // halfway between the largest low value and the smallest high value.
    let mut v = vec![0.1f32; 10];
    v.extend(vec![0.8f32; 10]);
    let p = Plane::<Unspecified>::from_vec(20, 1, v).unwrap();
    let t = otsu_threshold(&p);
    assert!((t - 0.45).abs() < 1e-6, "t = {t}");
    assert_eq!(p.threshold(t).count(), 10);
}

#[test]
fn otsu_keeps_resolution_for_dim_values() {
    // Dim values (as in a dark scene's white − black difference): noise around 0.001 and a
    // lit level around 0.012, all below 4/255. An 8-bit histogram would merge them.
    let mut v = Vec::new();
    for i in 0..100 {
        v.push(0.0005 + 0.00001 * i as f32);
    }
    for i in 0..60 {
        v.push(0.011 + 0.00002 * i as f32);
    }
    let t = otsu_threshold_values(&v);
    assert!(t > 0.0015 && t < 0.011, "t = {t}");
    assert_eq!(v.iter().filter(|&&x| x > t).count(), 60);
}

#[test]
fn otsu_three_clusters_picks_the_larger_gap_split() {
    // 0.0 ×50, 0.5 ×5, 1.0 ×45. Between-class variance for split {0}|{0.5,1}:
    // w0 w1 (μ0−μ1)² = 50·50·(0 − 0.95)² = 2256; for {0,0.5}|{1}: 55·45·(0.04545 − 1)² = 2255.
    // So the first split wins, narrowly: threshold halfway between 0 and 0.5.
    let mut v = vec![0.0f32; 50];
    v.extend(vec![0.5f32; 5]);
    v.extend(vec![1.0f32; 45]);
    let t = otsu_threshold_values(&v);
    assert!((t - 0.25).abs() < 1e-6, "t = {t}");
}

#[test]
fn otsu_constant_and_empty() {
    assert_eq!(otsu_threshold_values(&[0.3; 7]), 0.3);
    assert_eq!(otsu_threshold_values(&[]), 0.0);
    assert_eq!(otsu_threshold_values(&[f32::NAN, 0.2]), 0.2);
}

#[test]
fn components_use_8_connectivity() {
    let mask = m(&[
        "##....", //
        "..#...", // diagonal link to the pair above
        "......", //
        "....##", //
        "....##", //
    ]);
    let cc = connected_components(&mask);
    assert_eq!(cc.count(), 2);
    assert_eq!(cc.label(0, 0), 1);
    assert_eq!(cc.label(2, 1), 1);
    assert_eq!(cc.label(4, 3), 2);
    assert_eq!(cc.size(1), 3);
    assert_eq!(cc.size(2), 4);
    assert_eq!(cc.largest(), Some(2));
    assert_eq!(
        show(&largest_component(&mask)),
        ["......", "......", "......", "....##", "....##"]
    );
}

#[test]
fn largest_component_ties_take_the_first_and_empty_stays_empty() {
    let mask = m(&["#.#"]);
    assert_eq!(show(&largest_component(&mask)), ["#.."]);
    let empty = m(&["..."]);
    assert_eq!(connected_components(&empty).largest(), None);
    assert_eq!(largest_component(&empty).count(), 0);
}

#[test]
fn major_components_keep_the_big_ones() {
    // Sizes 6, 3 and 1.
    let mask = m(&[
        "###..#", //
        "###...", //
        "......", //
        "##....", //
        "#.....", //
    ]);
    assert_eq!(
        show(&major_components(&mask, 0.5)),
        ["###...", "###...", "......", "##....", "#....."]
    );
    assert_eq!(
        show(&major_components(&mask, 1.0)),
        show(&largest_component(&mask))
    );
    assert_eq!(major_components(&mask, 0.1).count(), 10);
    assert_eq!(major_components(&m(&["..."]), 0.5).count(), 0);
}

#[test]
fn fill_holes_fills_enclosed_background_only() {
    let mask = m(&[
        "#####...", //
        "#..##...", // hole of two pixels
        "#####..#", //
        "......#.", //
        ".###...#", // this notch is open to the border below
        ".#.#....", //
    ]);
    let expected = [
        "#####...", //
        "#####...", //
        "#####..#", //
        "......#.", //
        ".###...#", //
        ".#.#....", //
    ];
    assert_eq!(show(&fill_holes(&mask)), expected);
    // A ring closed only through diagonal steps still encloses its centre (4-connected
    // background).
    let ring = m(&[".....", "..#..", ".#.#.", "..#..", "....."]);
    assert_eq!(
        show(&fill_holes(&ring)),
        [".....", "..#..", ".###.", "..#..", "....."]
    );
}

#[test]
fn hull_of_an_l_shape() {
    let mask = m(&[
        "#.....", //
        "#.....", //
        "#.....", //
        "######", //
    ]);
    // Hull vertices: (0,0), (0,3), (5,3) — a right triangle. Pixel centres inside or on it:
    // row y has x ≤ 5·y/3.
    let hull = convex_hull(&mask);
    assert_eq!(hull.len(), 3, "{hull:?}");
    for v in [(0, 0), (0, 3), (5, 3)] {
        assert!(hull.contains(&v), "{hull:?}");
    }
    assert_eq!(
        show(&convex_hull_fill(&mask)),
        ["#.....", "##....", "####..", "######"]
    );
}

#[test]
fn hull_degenerate_cases() {
    let one = m(&["....", ".#..", "...."]);
    assert_eq!(convex_hull(&one), vec![(1, 1)]);
    assert_eq!(show(&convex_hull_fill(&one)), show(&one));
    // Two pixels on a diagonal: the segment's lattice points are exactly its three pixels.
    let diag = m(&["#...", "....", "..#."]);
    assert_eq!(convex_hull(&diag).len(), 2);
    assert_eq!(show(&convex_hull_fill(&diag)), ["#...", ".#..", "..#."]);
    assert!(convex_hull(&m(&["..."])).is_empty());
}

#[test]
fn hull_of_a_diamond_keeps_the_diamond() {
    let diamond = m(&[
        "...#...", //
        "..###..", //
        ".#####.", //
        "..###..", //
        "...#...", //
    ]);
    assert_eq!(show(&convex_hull_fill(&diamond)), show(&diamond));
    // Removing the inside changes nothing in the hull.
    let outline = m(&[
        "...#...", //
        "..#.#..", //
        ".#...#.", //
        "..#.#..", //
        "...#...", //
    ]);
    assert_eq!(show(&convex_hull_fill(&outline)), show(&diamond));
}

#[test]
fn integral_counts() {
    let mask = m(&["#.#", "###", "..#"]);
    let sat = IntegralMask::new(&mask);
    assert_eq!(sat.count_in(0, 0, 3, 3), 6);
    assert_eq!(sat.count_in(1, 0, 3, 2), 3);
    assert_eq!(sat.count_in(2, 0, 9, 9), 3); // clipped
    assert!(sat.all_set(0, 1, 3, 1));
    assert!(!sat.all_set(0, 0, 2, 2));
    assert!(!sat.all_set(2, 2, 1, 2)); // leaves the image
}

#[test]
fn dilate_and_erode_square_and_disk() {
    let dot = m(&[".....", ".....", "..#..", ".....", "....."]);
    assert_eq!(
        show(&dilate(&dot, Element::Square(1))),
        [".....", ".###.", ".###.", ".###.", "....."]
    );
    // Disk of radius 1: the 4 edge neighbours only (diagonals are at distance √2 > 1).
    assert_eq!(
        show(&dilate(&dot, Element::Disk(1))),
        [".....", "..#..", ".###.", "..#..", "....."]
    );
    // Disk of radius 2 includes the diagonals (√2) but not (2,1)-offsets (√5).
    assert_eq!(
        show(&dilate(&dot, Element::Disk(2))),
        ["..#..", ".###.", "#####", ".###.", "..#.."]
    );
    let block = m(&["#####", "#####", "#####", "####.", "#####"]);
    // Erosion: the edge counts as background, so only (1..=3, 1..=3) can survive, and those
    // whose element reaches the missing pixel (4,3) go: (3,2) and (3,3) for the square,
    // only its edge neighbour (3,3) for the radius-1 disk.
    assert_eq!(
        show(&erode(&block, Element::Square(1))),
        [".....", ".###.", ".##..", ".##..", "....."]
    );
    assert_eq!(
        show(&erode(&block, Element::Disk(1))),
        [".....", ".###.", ".###.", ".##..", "....."]
    );
}

#[test]
fn morphology_of_empty_and_full_masks() {
    let empty = m(&[".....", ".....", "....."]);
    for el in [Element::Square(1), Element::Disk(2)] {
        assert_eq!(dilate(&empty, el).count(), 0);
        assert_eq!(close(&empty, el).count(), 0);
    }
    let full = m(&["#####", "#####", "#####"]);
    // Radius 1: only the middle row's inner pixels are one pixel away from the edge.
    for el in [Element::Square(1), Element::Disk(1)] {
        assert_eq!(show(&erode(&full, el)), [".....", ".###.", "....."]);
        assert_eq!(show(&close(&full, el)), show(&full));
    }
    // Opening is the union of element placements inside the mask (the outside being
    // background): squares cover the whole rectangle, crosses cannot reach its corners.
    assert_eq!(show(&open(&full, Element::Square(1))), show(&full));
    assert_eq!(
        show(&open(&full, Element::Disk(1))),
        [".###.", "#####", ".###."]
    );
}

#[test]
fn closing_fills_a_gap_and_opening_removes_a_spur() {
    let gap = m(&[
        "........", //
        ".##.###.", //
        ".##.###.", //
        "........", //
    ]);
    assert_eq!(
        show(&close(&gap, Element::Square(1))),
        ["........", ".######.", ".######.", "........"]
    );
    // Closing near the image edge keeps the unset margin (padded computation) and never
    // removes pixels.
    let edge = m(&["#....", "#....", "#...."]);
    assert_eq!(show(&close(&edge, Element::Disk(2))), show(&edge));
    let spur = m(&[
        ".......", //
        ".###...", //
        ".######", // a one-pixel-high spur to the right
        ".###...", //
        ".......", //
    ]);
    assert_eq!(
        show(&open(&spur, Element::Square(1))),
        [".......", ".###...", ".###...", ".###...", "......."]
    );
}

#[test]
fn closing_a_one_pixel_notch_square_versus_disk() {
    // A 1-pixel notch into the top edge of a block. The square fills it. A Euclidean disk
    // has a one-pixel tip (offset (0, r) is in it, (±1, r) are not), so a disk centred above
    // the block touches the notch without meeting the block: disk closing leaves it.
    let notch = m(&[
        ".......", //
        ".##.##.", //
        ".#####.", //
        ".#####.", //
        ".......", //
    ]);
    assert_eq!(
        show(&close(&notch, Element::Square(1))),
        [".......", ".#####.", ".#####.", ".#####.", "......."]
    );
    assert_eq!(show(&close(&notch, Element::Disk(2))), show(&notch));
}
