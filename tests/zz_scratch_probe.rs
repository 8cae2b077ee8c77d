use nvtmm::math::Vec3;
#[test]
fn probe() {
    for f in ["/tmp/v14b/b5832.msh", "/tmp/v14b/u5832.msh"] {
        let m = nvtmm::mesh::io::read_mesh(std::path::Path::new(f)).unwrap();
        let c = Vec3::new(0.0065, -0.031, 0.177);
        let outer = m.node_set("outer_wall").unwrap();
        let labels = m.segment_labels();
        let mut near: Vec<(f64, u32)> = outer.iter().map(|&i| ((m.rest()[i as usize] - c).norm(), i)).collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        println!(
            "{f}: nearest outer {:.2} mm at {:?}",
            near[0].0 * 1e3,
            m.rest()[near[0].1 as usize] * 1e3
        );
        let within: Vec<u32> = near.iter().filter(|x| x.0 < 0.015).map(|x| x.1).collect();
        println!("  {} outer nodes within 15 mm", within.len());
        if let Some((names, l)) = &labels {
            let mut cnt = vec![0; names.len()];
            for &i in &within {
                cnt[l[i as usize] as usize] += 1;
            }
            println!("  labels {names:?} {cnt:?}");
        }
        let (lo, hi) = m.bbox();
        println!("  bbox {:?} {:?}", lo * 1e3, hi * 1e3);
    }
}
