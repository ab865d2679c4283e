//! Unit tests of the codes and the pattern sequence.

use super::*;

#[test]
fn bits_and_lengths() {
    assert_eq!(bits_for(1), 0);
    assert_eq!(bits_for(2), 1);
    assert_eq!(bits_for(3), 2);
    assert_eq!(bits_for(4), 2);
    assert_eq!(bits_for(5), 3);
    assert_eq!(bits_for(600), 10);
    assert_eq!(bits_for(800), 10);
    assert_eq!(bits_for(1024), 10);
    assert_eq!(bits_for(1025), 11);
    assert_eq!(GrayCode::new(800, 600).unwrap().len(), 42);
    assert_eq!(GrayCode::new(1, 1).unwrap().len(), 2);
    assert!(GrayCode::new(0, 10).is_err());
}

#[test]
fn gray_round_trip_and_adjacency() {
    for v in 0..5000u32 {
        assert_eq!(from_gray(to_gray(v)), v);
        // Neighbouring codes differ in exactly one bit.
        assert_eq!((to_gray(v) ^ to_gray(v + 1)).count_ones(), 1);
    }
    assert_eq!(from_gray(to_gray(u32::MAX)), u32::MAX);
}

#[test]
fn sequence_order() {
    let g = GrayCode::new(8, 4).unwrap(); // 3 column bits, 2 row bits
    assert_eq!(g.len(), 12);
    assert_eq!(g.kind(0), Some(PatternKind::White));
    assert_eq!(g.kind(1), Some(PatternKind::Black));
    assert_eq!(
        g.kind(2),
        Some(PatternKind::Column {
            bit: 0,
            inverted: false
        })
    );
    assert_eq!(
        g.kind(7),
        Some(PatternKind::Column {
            bit: 2,
            inverted: true
        })
    );
    assert_eq!(
        g.kind(8),
        Some(PatternKind::Row {
            bit: 0,
            inverted: false
        })
    );
    assert_eq!(
        g.kind(11),
        Some(PatternKind::Row {
            bit: 1,
            inverted: true
        })
    );
    assert_eq!(g.kind(12), None);
    assert!(g.pattern(12).is_err());
    // MSB column pattern of an 8-wide projector: Gray codes 0,1,3,2,6,7,5,4 → MSB 0,0,0,0,1,1,1,1.
    let p = g.pattern(2).unwrap();
    let row: Vec<f32> = (0..8).map(|x| p.get(x, 3)[0]).collect();
    assert_eq!(row, vec![0., 0., 0., 0., 1., 1., 1., 1.]);
    // LSB: bits 0,1,1,0,0,1,1,0 and the inverse is the complement.
    let p = g.pattern(6).unwrap();
    let q = g.pattern(7).unwrap();
    let row: Vec<f32> = (0..8).map(|x| p.get(x, 0)[1]).collect();
    assert_eq!(row, vec![0., 1., 1., 0., 0., 1., 1., 0.]);
    for (a, b) in p.data().iter().zip(q.data()) {
        assert_eq!(a + b, 1.0);
    }
}
