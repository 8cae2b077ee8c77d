//! The guidewire polyline of a state frame (stream format version 2)
//! survives encoding, chunking into datagrams and decoding, and a frame
//! with more points than the format allows is refused by the decoder.

use nvtmm::stream::format::{chunk_message, encode_state, encode_topology, KIND_STATE, KIND_TOPOLOGY, VERSION};
use nvtmm::stream::{Decoded, Decoder, StateFrame, Topology, MAX_WIRE_POINTS};

fn topology() -> Topology {
    Topology {
        epoch: 1,
        rest_positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        triangles: vec![[0, 1, 2]],
        node_ids: vec![0, 1, 2],
    }
}

fn send(dec: &mut Decoder, kind: u8, seq: u32, msg: &[u8]) -> Vec<Decoded> {
    let mut out = Vec::new();
    let mut buf = Vec::new();
    let mut grams = Vec::new();
    chunk_message(kind, seq, 1, msg, 200, &mut buf, |d| grams.push(d.to_vec())).unwrap();
    for g in grams.iter().rev() {
        if let Ok(Some(m)) = dec.push(g) {
            out.push(m);
        }
    }
    out
}

#[test]
fn the_wire_polyline_round_trips_and_oversized_ones_are_refused() {
    assert_eq!(VERSION, 2);
    let mut dec = Decoder::new();
    let mut msg = Vec::new();
    encode_topology(&topology(), &mut msg);
    assert_eq!(send(&mut dec, KIND_TOPOLOGY, 0, &msg).len(), 1);
    let positions = [[0.0f32; 3]; 3];
    let wire: Vec<[f32; 3]> = (0..MAX_WIRE_POINTS)
        .map(|k| [k as f32 * 1e-3, (k as f32 * 0.1).sin() * 1e-2, 0.25 - k as f32 * 1e-4])
        .collect();
    for (seq, n) in [(1u32, 0usize), (2, 1), (3, 37), (4, MAX_WIRE_POINTS)] {
        let f = StateFrame {
            time_s: seq as f64,
            positions: &positions,
            tool_position: [0.0; 3],
            tool_radius: 0.003,
            force: [0.0; 3],
            flags: 0,
            loop_rate_hz: 1000.0,
            tick_p99_us: 10.0,
            wire: &wire[..n],
        };
        msg.clear();
        encode_state(&f, &mut msg);
        let got = send(&mut dec, KIND_STATE, seq, &msg);
        match got.as_slice() {
            [Decoded::State(s)] => {
                assert_eq!(s.wire.len(), n);
                assert_eq!(s.wire.as_slice(), &wire[..n]);
                assert_eq!(s.positions.len(), 3);
                // Re-encoding the decoded frame gives the same bytes.
                let mut again = Vec::new();
                encode_state(&s.as_frame(), &mut again);
                assert_eq!(again, msg);
            }
            other => panic!("frame with {n} wire points: {other:?}"),
        }
    }
    // One point too many: the payload is refused.
    let mut long = wire.clone();
    long.push([0.0; 3]);
    let f = StateFrame {
        time_s: 9.0,
        positions: &positions,
        tool_position: [0.0; 3],
        tool_radius: 0.003,
        force: [0.0; 3],
        flags: 0,
        loop_rate_hz: 1000.0,
        tick_p99_us: 10.0,
        wire: &long,
    };
    msg.clear();
    encode_state(&f, &mut msg);
    assert!(send(&mut dec, KIND_STATE, 9, &msg).is_empty());
    assert!(dec.stats().total_rejected() > 0);
}
