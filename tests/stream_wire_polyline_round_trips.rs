//! The instruments' polylines of a state frame (stream format version 3:
//! one polyline per instrument, with its id and kind) survive encoding,
//! chunking into datagrams and decoding; a frame with more points per
//! instrument, or more instruments, than the format allows is refused by
//! the decoder; and a version 2 frame (the guidewire's polyline alone)
//! still decodes, as one guidewire instrument.

use nvtmm::stream::format::{
    chunk_message, encode_state, encode_topology, KIND_STATE, KIND_TOPOLOGY, MAX_CHUNK_PAYLOAD, STATE_FIXED_LEN,
    VERSION, VERSION_2,
};
use nvtmm::stream::{
    Decoded, Decoder, InstrumentLine, StateFrame, Topology, MAX_FRAME_INSTRUMENTS, MAX_INSTRUMENT_POINTS,
};

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

fn frame<'a>(seq: u32, positions: &'a [[f32; 3]], lines: &'a [InstrumentLine<'a>]) -> StateFrame<'a> {
    StateFrame {
        time_s: seq as f64,
        positions,
        tool_position: [0.0; 3],
        tool_radius: 0.003,
        force: [0.0; 3],
        flags: 0,
        loop_rate_hz: 1000.0,
        tick_p99_us: 10.0,
        instruments: lines,
    }
}

#[test]
fn each_instruments_polyline_round_trips_with_its_id_and_kind() {
    assert_eq!(VERSION, 3);
    let mut dec = Decoder::new();
    let mut msg = Vec::new();
    encode_topology(&topology(), &mut msg);
    assert_eq!(send(&mut dec, KIND_TOPOLOGY, 0, &msg).len(), 1);
    let positions = [[0.0f32; 3]; 3];
    let wire: Vec<[f32; 3]> = (0..MAX_INSTRUMENT_POINTS)
        .map(|k| [k as f32 * 1e-3, (k as f32 * 0.1).sin() * 1e-2, 0.25 - k as f32 * 1e-4])
        .collect();
    let probe = [[0.01f32, 0.02, 0.03]];
    for (seq, n) in [(1u32, 0usize), (2, 1), (3, 37), (4, MAX_INSTRUMENT_POINTS)] {
        // The probe, the wire with n points, and an unknown kind 7 with an
        // id out of order: ids and kinds are carried, not interpreted.
        let lines = [
            InstrumentLine {
                id: 0,
                kind: 1,
                points: &probe,
            },
            InstrumentLine {
                id: 1,
                kind: 2,
                points: &wire[..n],
            },
            InstrumentLine {
                id: 5,
                kind: 7,
                points: &wire[..n / 2],
            },
        ];
        msg.clear();
        encode_state(&frame(seq, &positions, &lines), &mut msg);
        let got = send(&mut dec, KIND_STATE, seq, &msg);
        match got.as_slice() {
            [Decoded::State(s)] => {
                assert_eq!(s.instruments.len(), 3);
                for (l, o) in lines.iter().zip(&s.instruments) {
                    assert_eq!((o.id, o.kind), (l.id, l.kind));
                    assert_eq!(o.points.as_slice(), l.points);
                }
                assert_eq!(s.polyline_of_kind(2), &wire[..n]);
                assert_eq!(s.positions.len(), 3);
                // Re-encoding the decoded frame gives the same bytes.
                let mut again = Vec::new();
                let decoded_lines = s.lines();
                encode_state(&s.as_frame(&decoded_lines), &mut again);
                assert_eq!(again, msg);
            }
            other => panic!("frame with {n} wire points: {other:?}"),
        }
    }
    // One point too many, and one instrument too many: refused.
    let mut long = wire.clone();
    long.push([0.0; 3]);
    let too_long = [InstrumentLine {
        id: 0,
        kind: 2,
        points: &long,
    }];
    let too_many: Vec<InstrumentLine<'_>> = (0..=MAX_FRAME_INSTRUMENTS)
        .map(|k| InstrumentLine {
            id: k as u8,
            kind: 1,
            points: &probe,
        })
        .collect();
    for (seq, lines) in [(9u32, &too_long[..]), (10, &too_many[..])] {
        msg.clear();
        encode_state(&frame(seq, &positions, lines), &mut msg);
        let before = dec.stats().total_rejected();
        assert!(send(&mut dec, KIND_STATE, seq, &msg).is_empty());
        assert!(dec.stats().total_rejected() > before);
    }
}

#[test]
fn a_version_2_frame_decodes_as_one_guidewire() {
    let mut dec = Decoder::new();
    let mut msg = Vec::new();
    encode_topology(&topology(), &mut msg);
    assert_eq!(send(&mut dec, KIND_TOPOLOGY, 0, &msg).len(), 1);
    // A version 3 frame without instruments is the version 2 layout with
    // no wire points: append the v2 wire section by hand.
    let positions = [[0.5f32; 3]; 3];
    msg.clear();
    encode_state(&frame(1, &positions, &[]), &mut msg);
    assert_eq!(msg.len(), STATE_FIXED_LEN + 12 * 3 + 4);
    let wire = [[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]];
    let n = msg.len() - 4;
    msg[n..].copy_from_slice(&(wire.len() as u32).to_le_bytes());
    for p in wire {
        for c in p {
            msg.extend_from_slice(&c.to_le_bytes());
        }
    }
    let mut buf = Vec::new();
    let mut grams = Vec::new();
    chunk_message(KIND_STATE, 1, 1, &msg, MAX_CHUNK_PAYLOAD, &mut buf, |d| {
        grams.push(d.to_vec())
    })
    .unwrap();
    let mut got = None;
    for mut g in grams {
        g[4..6].copy_from_slice(&VERSION_2.to_le_bytes());
        if let Ok(Some(m)) = dec.push(&g) {
            got = Some(m);
        }
    }
    match got {
        Some(Decoded::State(s)) => {
            assert_eq!(s.instruments.len(), 1);
            assert_eq!((s.instruments[0].id, s.instruments[0].kind), (0, 2));
            assert_eq!(s.instruments[0].points, wire.to_vec());
            assert_eq!(s.positions, positions.to_vec());
        }
        other => panic!("{other:?}"),
    }
}
