//! The sphere probe: a rigid sphere at the stylus tip, the first instrument
//! and the simplest. Its contact is not computed here but resolved by the
//! vessel step itself, implicitly, since the probe's force is the wall's
//! reaction on the sphere and the reduced step has the contact stiffness
//! inside (`crate::haptics::servo`): the probe contributes the request for a
//! sphere at the hand ([`Contribution::hand_sphere`]), and the hand feels
//! that sphere's reaction. No thread of its own; its polyline on the stream
//! is the one point of the sphere's centre.

use super::{BuildContext, Built, Hand, InstrumentReport, Kind, LoopSide, PublisherSide, ServiceSide, VesselView};
use crate::haptics::tick::Contribution;
use crate::service::report::Report;
use crate::service::ServiceError;

/// The probe's kind.
pub const KIND: Kind = Kind { name: "probe", code: 1 };

/// Every run has the probe: the stylus tip touches the vessel wherever the
/// hand takes it (with a guidewire too, as the hand's own sphere).
pub fn build<const R: usize>(ctx: &BuildContext<'_, R>) -> Result<Vec<Built>, ServiceError> {
    Ok(vec![Built {
        id: "probe",
        kind: KIND,
        loop_side: Box::new(ProbeLoop),
        publisher_side: Box::new(ProbePublisher { point: [[0.0; 3]] }),
        service_side: Box::new(ProbeService {
            radius_m: ctx.cfg.contact.tool_radius_m,
        }),
    }])
}

struct ProbeLoop;

impl LoopSide for ProbeLoop {
    fn contribute(&mut self, _hand: &Hand<'_>) -> Contribution<'_> {
        Contribution::PROBE
    }
}

struct ProbePublisher {
    point: [[f32; 3]; 1],
}

impl PublisherSide for ProbePublisher {
    fn update(&mut self, view: &VesselView<'_>) {
        let t = view.tool;
        self.point = [[t.x as f32, t.y as f32, t.z as f32]];
    }

    fn polyline(&self) -> &[[f32; 3]] {
        &self.point
    }
}

struct ProbeService {
    radius_m: f64,
}

impl ServiceSide for ProbeService {
    fn finish(&mut self, report: &mut Report) -> Result<InstrumentReport, ServiceError> {
        let keys = serde_json::json!({
            "tool_radius_m": self.radius_m,
            "max_depth_m": report.max_depth_m,
            "contact_ticks": report.watchdog.contact_ticks,
        });
        Ok(InstrumentReport {
            id: "probe".into(),
            kind: KIND.name.into(),
            faults: 0,
            keys,
            summary: format!(
                "sphere of {:.1} mm, deepest {:.2} mm, {} contact ticks",
                self.radius_m * 1e3,
                report.max_depth_m * 1e3,
                report.watchdog.contact_ticks
            ),
        })
    }
}
