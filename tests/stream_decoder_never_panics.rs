//! The stream decoder takes any bytes without panicking, counts what it
//! rejects, and reassembles valid datagrams in any arrival order.

use nvtmm::stream::format::{
    chunk_message, encode_state, encode_topology, KIND_STATE, KIND_TOPOLOGY, MAX_CHUNK_PAYLOAD,
};
use nvtmm::stream::{Decoded, Decoder, StateFrame, Topology};
use proptest::prelude::*;

fn topology(n: usize) -> Topology {
    Topology {
        epoch: 7,
        rest_positions: (0..n).map(|i| [i as f32 * 1e-3, 1.0, -1.0]).collect(),
        triangles: (0..n - 2).map(|i| [i as u32, i as u32 + 1, i as u32 + 2]).collect(),
        node_ids: (0..n as u32).collect(),
    }
}

/// Datagrams of: the topology (seq 0), then `states` state frames (seq 1..).
fn stream(n: usize, states: usize) -> (Vec<Vec<Vec<u8>>>, Topology) {
    let t = topology(n);
    let mut msgs = Vec::new();
    let mut buf = Vec::new();
    let mut m = Vec::new();
    encode_topology(&t, &mut m);
    let mut one = Vec::new();
    chunk_message(KIND_TOPOLOGY, 0, t.epoch, &m, MAX_CHUNK_PAYLOAD, &mut buf, |d| {
        one.push(d.to_vec())
    })
    .unwrap();
    msgs.push(one);
    for k in 0..states {
        let pos: Vec<[f32; 3]> = t.rest_positions.iter().map(|p| [p[0], p[1], p[2] + k as f32]).collect();
        let f = StateFrame {
            time_s: k as f64,
            positions: &pos,
            tool_position: [0.0; 3],
            tool_radius: 0.001,
            force: [k as f32, 0.0, 0.0],
            flags: 0,
            loop_rate_hz: 1000.0,
            tick_p99_us: 20.0,
            instruments: &[],
        };
        m.clear();
        encode_state(&f, &mut m);
        let mut one = Vec::new();
        chunk_message(
            KIND_STATE,
            1 + k as u32,
            t.epoch,
            &m,
            MAX_CHUNK_PAYLOAD,
            &mut buf,
            |d| one.push(d.to_vec()),
        )
        .unwrap();
        msgs.push(one);
    }
    (msgs, t)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn arbitrary_bytes_never_panic(ds in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..1400), 0..40)) {
        let mut dec = Decoder::new();
        for d in &ds {
            let _ = dec.push(d);
        }
        prop_assert_eq!(dec.stats().datagrams, ds.len() as u64);
    }

    #[test]
    fn corrupted_datagrams_never_panic_and_are_counted(
        states in 1usize..4,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<prop::sample::Index>(), any::<u8>(), 0u8..4), 1..30),
    ) {
        let (msgs, _) = stream(150, states);
        let mut ds: Vec<Vec<u8>> = msgs.into_iter().flatten().collect();
        for (which, at, byte, op) in &edits {
            let i = which.index(ds.len());
            let d = &mut ds[i];
            // An earlier edit may have truncated it to nothing: leave it
            // empty (the decoder must still count it), nothing to index.
            if d.is_empty() && *op < 3 {
                continue;
            }
            match op {
                0 => { let j = at.index(d.len()); d[j] = *byte; }
                1 => { let j = at.index(d.len()); d.truncate(j); }
                2 => { let j = at.index(28.min(d.len())); d[j] ^= *byte | 1; }
                _ => { let c = d.clone(); ds.push(c); }
            }
        }
        let mut dec = Decoder::new();
        let mut delivered = 0u64;
        for d in &ds {
            if let Ok(Some(_)) = dec.push(d) {
                delivered += 1;
            }
        }
        let s = dec.stats();
        prop_assert_eq!(s.datagrams, ds.len() as u64);
        prop_assert_eq!(delivered, s.topologies + s.states);
    }

    #[test]
    fn any_arrival_order_reassembles_every_message(states in 1usize..4, seed in any::<u64>()) {
        let (msgs, t) = stream(200, states);
        let total = msgs.len() as u64;
        let mut ds: Vec<Vec<u8>> = msgs.into_iter().flatten().collect();
        // Fisher-Yates with a small LCG: proptest shrinks the seed.
        let mut x = seed | 1;
        for i in (1..ds.len()).rev() {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ds.swap(i, (x >> 33) as usize % (i + 1));
        }
        let mut dec = Decoder::new();
        for d in &ds {
            match dec.push(d) {
                Ok(Some(Decoded::Topology(got))) => prop_assert_eq!(&got, &t),
                Ok(Some(Decoded::State(s))) => prop_assert_eq!(s.force[0] as f64, s.time_s),
                Ok(None) => {}
                Err(r) => prop_assert!(false, "rejected {:?}", r),
            }
        }
        let s = dec.stats();
        prop_assert_eq!(s.topologies + s.states + s.stale + s.awaiting_topology, total);
        prop_assert_eq!(s.gaps, 0);
        prop_assert_eq!(s.total_rejected(), 0);
    }
}

#[test]
fn lost_messages_are_reported_as_gaps() {
    let (msgs, _) = stream(100, 6);
    let mut dec = Decoder::new();
    for (k, m) in msgs.iter().enumerate() {
        if k == 2 || k == 4 {
            continue; // two state frames lost
        }
        for d in m {
            dec.push(d).unwrap();
        }
    }
    assert_eq!(dec.stats().gaps, 2);
    assert_eq!(dec.stats().states, 4);
    // A message that loses one chunk never completes; it is dropped once
    // newer messages crowd it out.
    let (msgs, _) = stream(400, 12);
    let mut dec = Decoder::new();
    for (k, m) in msgs.iter().enumerate() {
        for (j, d) in m.iter().enumerate() {
            if k == 1 && j == 1 {
                continue;
            }
            dec.push(d).unwrap();
        }
    }
    assert_eq!(dec.stats().states, 11);
    assert_eq!(dec.stats().gaps, 1);
    assert_eq!(dec.stats().incomplete, 1);
}
