//! The message relocd publishes for every relocalisation: versioned, in JSON or MessagePack, one per
//! datagram. `docs/protocol.md` is its contract; this module is the reference encoder and decoder.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::geometry::Representation;

/// The schema version this relocd writes. A change that breaks readers bumps it; new optional keys do
/// not.
pub const SCHEMA_VERSION: u32 = 1;

/// How messages are encoded on the wire.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// UTF-8 JSON object.
    #[default]
    Json,
    /// A MessagePack map with the same keys as the JSON object.
    Msgpack,
}

impl std::str::FromStr for Encoding {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name {
            "json" => Ok(Self::Json),
            "msgpack" => Ok(Self::Msgpack),
            _ => Err(format!("unknown encoding {name:?}: expected json or msgpack")),
        }
    }
}

/// Why bytes are not a relocd message.
#[derive(Debug, Error)]
pub enum MessageError {
    /// Neither JSON nor MessagePack of the expected shape.
    #[error("not a relocd message: {0}")]
    Malformed(String),
    /// Written by a relocd with another schema.
    #[error("relocd message schema {found}, this reader understands {SCHEMA_VERSION}")]
    Schema {
        /// The schema in the message.
        found: u32,
    },
    /// A value outside its range.
    #[error("relocd message: {0}")]
    Invalid(String),
}

/// What made relocd relocalise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TriggerKind {
    /// The GameController ended our player's penalty: a referee put the robot back.
    PenaltyReturn,
    /// The robot fell and got up.
    Fall,
    /// The robot was lifted and put down.
    PickUp,
    /// Someone asked on the control socket.
    Request,
}

/// One trigger answered by a message.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trigger {
    /// Unique per daemon run, counting from 1.
    pub id: u64,
    /// What happened.
    pub kind: TriggerKind,
    /// Detail: the penalty that ended, or the requester's reason.
    #[serde(default)]
    pub reason: Option<String>,
    /// When it arrived, Unix seconds.
    pub t: f64,
}

/// The model that produced the hypotheses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    /// The contract's model id.
    pub id: String,
    /// The representation it predicts in.
    pub representation: Representation,
}

/// Frames of the burst.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameCounts {
    /// Frames asked for.
    pub requested: u32,
    /// Frames relocalised and fused.
    pub used: u32,
    /// Used frames that agree with the best hypothesis.
    pub agreeing: u32,
}

/// Where the time went, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Latency {
    /// From the first trigger to the start of capture (settling, rate limit).
    pub wait: f64,
    /// Capturing the burst.
    pub capture: f64,
    /// Frame → input tensor, summed over the burst.
    pub preprocess: f64,
    /// The network, summed over the burst.
    pub inference: f64,
    /// Decoding, fusion and the prior.
    pub fusion: f64,
    /// Line percepts (summed over the burst) and line refinement; 0 when refinement is off.
    #[serde(default)]
    pub refine: f64,
    /// From the first trigger to publishing.
    pub total: f64,
}

/// What the field lines made of a hypothesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LineCheck {
    /// The lines fix x, y and heading, each to a line-only σ of at most 6 cm and 1.15°, with at least
    /// 12 points off the main line direction: the pose and σ are the line fit's.
    Refined,
    /// The lines fit but fix less (one family of parallel lines, or a wider σ).
    Partial,
    /// Too few line points: the network's hypothesis as it was.
    Unrefined,
    /// The lines seen do not fit this pose cleanly: the network's pose, with its weight cut.
    Contradicted,
    /// The lines fit this pose and other places on the field as well (`places` says how many): the
    /// network and the priors weigh them.
    Ambiguous,
}

/// The field lines' evidence about a hypothesis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LineEvidence {
    /// What was done with the hypothesis.
    pub check: LineCheck,
    /// Line points used, over all frames of the burst.
    pub points: usize,
    /// Share of the points on a field line under the pose.
    pub inlier_share: f64,
    /// Share of the lines the camera should have seen under the pose that it did not; absent when too
    /// few were expected to tell.
    pub unseen_share: Option<f64>,
    /// How many places on the field (a point-symmetric pair counted once) the lines fit, when the
    /// global search looked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub places: Option<usize>,
}

/// One weighted full-field robot pose.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hypothesis {
    /// Metres along the field's long axis, towards the opponent goal.
    pub x: f64,
    /// Metres to the left.
    pub y: f64,
    /// Heading, radians in (−π, π], 0 facing the opponent goal.
    pub theta: f64,
    /// Probability; a message's weights sum to 1.
    pub weight: f64,
    /// Standard deviations of x, y (metres) and theta (radians).
    pub sigma: [f64; 3],
    /// What the field lines said about this hypothesis, when refinement is on. Point-symmetric twins
    /// always carry the same evidence: lines cannot tell them apart.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lines: Option<LineEvidence>,
}

/// One prior that re-weighted a message's hypotheses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AppliedPrior {
    /// `penalty_return`, `belief`, `own_half`, `ball`, or `floor` (the floor lifted a hypothesis the
    /// other priors pushed below its minimum share).
    pub name: String,
    /// Its factor for each hypothesis, in the order of `hypotheses`: relative likelihoods (the largest
    /// is 1), or for the floor what it multiplied each weight by.
    pub factors: Vec<f64>,
}

/// The message published once per relocalisation (or failure).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Message {
    /// [`SCHEMA_VERSION`].
    pub schema: u32,
    /// Counts messages of this daemon run from 1; a gap means a lost datagram.
    pub seq: u64,
    /// When it was published, Unix seconds.
    pub published: f64,
    /// When the burst's first frame was taken, Unix seconds; absent when no frame was.
    #[serde(default)]
    pub captured: Option<f64>,
    /// The triggers this message answers (several when they were coalesced into one burst).
    pub triggers: Vec<Trigger>,
    /// The model.
    pub model: ModelInfo,
    /// The burst's frames.
    pub frames: FrameCounts,
    /// The priors that re-weighted the hypotheses, joined by `+`, e.g. `penalty_return` or
    /// `belief+own_half+floor`; absent when none did.
    #[serde(default)]
    pub prior: Option<String>,
    /// What each prior did: its factor for each hypothesis, in the order of `hypotheses`. Absent when
    /// no prior applied.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub priors: Vec<AppliedPrior>,
    /// Where the time went.
    pub latency_ms: Latency,
    /// Full-field robot poses, heaviest first; empty when relocalisation failed.
    pub hypotheses: Vec<Hypothesis>,
    /// Why there are no hypotheses, when there are none.
    #[serde(default)]
    pub failure: Option<String>,
}

impl Message {
    /// Encodes the message for one datagram.
    pub fn encode(&self, encoding: Encoding) -> Vec<u8> {
        match encoding {
            Encoding::Json => serde_json::to_vec(self).expect("a message is plain data"),
            Encoding::Msgpack => rmp_serde::to_vec_named(self).expect("a message is plain data"),
        }
    }

    /// Decodes and checks one datagram in either encoding (JSON starts with `{`).
    pub fn decode(bytes: &[u8]) -> Result<Self, MessageError> {
        #[derive(Deserialize)]
        struct Schema {
            schema: u32,
        }
        let schema: Result<Schema, String> = if bytes.first() == Some(&b'{') {
            serde_json::from_slice(bytes).map_err(|error| error.to_string())
        } else {
            rmp_serde::from_slice(bytes).map_err(|error| error.to_string())
        };
        let found = schema.map_err(MessageError::Malformed)?.schema;
        if found != SCHEMA_VERSION {
            return Err(MessageError::Schema { found });
        }
        let message: Self = if bytes[0] == b'{' {
            serde_json::from_slice(bytes).map_err(|error| MessageError::Malformed(error.to_string()))?
        } else {
            rmp_serde::from_slice(bytes).map_err(|error| MessageError::Malformed(error.to_string()))?
        };
        message.validate()?;
        Ok(message)
    }

    fn validate(&self) -> Result<(), MessageError> {
        let invalid = |what: String| Err(MessageError::Invalid(what));
        if self.triggers.is_empty() {
            return invalid("a message answers at least one trigger".into());
        }
        for (index, h) in self.hypotheses.iter().enumerate() {
            let finite = [h.x, h.y, h.theta, h.weight].iter().chain(&h.sigma).all(|v| v.is_finite());
            if !finite || !(0.0..=1.0).contains(&h.weight) || h.sigma.iter().any(|&s| s < 0.0) {
                return invalid(format!("hypothesis {index} is not finite, weighted in [0, 1] with σ ≥ 0"));
            }
        }
        for prior in &self.priors {
            if prior.factors.len() != self.hypotheses.len()
                || prior.factors.iter().any(|f| !(f.is_finite() && *f >= 0.0))
            {
                return invalid(format!(
                    "prior {} needs one finite, non-negative factor per hypothesis",
                    prior.name
                ));
            }
        }
        if self.hypotheses.is_empty() != self.failure.is_some() {
            return invalid("a message has either hypotheses or a failure reason".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> Message {
        Message {
            schema: SCHEMA_VERSION,
            seq: 3,
            published: 1_763_900_000.25,
            captured: Some(1_763_900_000.0),
            triggers: vec![Trigger {
                id: 7,
                kind: TriggerKind::PenaltyReturn,
                reason: Some("pushing".into()),
                t: 1_763_899_999.5,
            }],
            model: ModelInfo {
                id: "squeezenet-half-point".into(),
                representation: Representation::HalfPoint,
            },
            frames: FrameCounts { requested: 5, used: 5, agreeing: 4 },
            prior: Some("penalty_return".into()),
            priors: vec![AppliedPrior { name: "penalty_return".into(), factors: vec![1.0, 0.002] }],
            latency_ms: Latency { total: 750.0, ..Latency::default() },
            hypotheses: vec![
                Hypothesis {
                    x: -3.1,
                    y: 3.4,
                    theta: -1.5,
                    weight: 0.97,
                    sigma: [0.02, 0.02, 0.01],
                    lines: Some(LineEvidence {
                        check: LineCheck::Refined,
                        points: 140,
                        inlier_share: 0.98,
                        unseen_share: Some(0.05),
                        places: None,
                    }),
                },
                Hypothesis {
                    x: 3.1,
                    y: -3.4,
                    theta: 1.64,
                    weight: 0.03,
                    sigma: [0.2, 0.2, 0.1],
                    lines: None,
                },
            ],
            failure: None,
        }
    }

    #[test]
    fn both_encodings_round_trip() {
        let message = example();
        for encoding in [Encoding::Json, Encoding::Msgpack] {
            assert_eq!(Message::decode(&message.encode(encoding)).unwrap(), message, "{encoding:?}");
        }
        let json: serde_json::Value = serde_json::from_slice(&message.encode(Encoding::Json)).unwrap();
        assert_eq!(json["triggers"][0]["kind"], "penalty_return");
        assert_eq!(json["model"]["representation"], "half-point");
        assert_eq!(json["hypotheses"][0]["sigma"][2], 0.01);
        assert_eq!(json["hypotheses"][0]["lines"]["check"], "refined");
        assert!(json["hypotheses"][1].get("lines").is_none(), "no key when refinement is off");
        assert_eq!(json["priors"][0]["factors"][1], 0.002);
        let mut plain = message.clone();
        plain.priors.clear();
        let json: serde_json::Value = serde_json::from_slice(&plain.encode(Encoding::Json)).unwrap();
        assert!(json.get("priors").is_none(), "schema 1 without priors looks as before");
    }

    #[test]
    fn other_schemas_and_broken_messages_are_refused() {
        let mut message = example();
        message.schema = 2;
        let error = Message::decode(&message.encode(Encoding::Msgpack)).unwrap_err();
        assert!(matches!(error, MessageError::Schema { found: 2 }), "{error}");
        assert!(matches!(Message::decode(b"{\"schema\":1}"), Err(MessageError::Malformed(_))));
        assert!(matches!(Message::decode(b""), Err(MessageError::Malformed(_))));
        assert!(matches!(Message::decode(b"\xc1\xff"), Err(MessageError::Malformed(_))));

        let mut failed = example();
        failed.failure = Some("camera gone".into());
        assert!(matches!(Message::decode(&failed.encode(Encoding::Json)), Err(MessageError::Invalid(_))));
        failed.hypotheses.clear();
        failed.priors.clear();
        assert!(Message::decode(&failed.encode(Encoding::Json)).is_ok());
        let mut short = example();
        short.priors[0].factors.pop();
        assert!(matches!(Message::decode(&short.encode(Encoding::Json)), Err(MessageError::Invalid(_))));
        let mut heavy = example();
        heavy.hypotheses[0].weight = 1.5;
        assert!(matches!(Message::decode(&heavy.encode(Encoding::Json)), Err(MessageError::Invalid(_))));
    }
}
