//! A gRPC `Retrain` stream into one upload: the header first, then shapes or subjects in as
//! many messages as needed; the total size is capped by `--max-upload` and hashed for the
//! version's provenance.

use facepose_core::shape::Point3;
use sha2::Digest;

use crate::proto::{self, retrain_chunk::Part};
use facepose_app::error::ServiceError;
use facepose_app::retrain::{RawGrid, RawOptions, RawUpload, SchemeSpec, UploadData};
use facepose_core::shape::Scheme;

fn raw_grid(g: &proto::PoseGrid, what: &str) -> Result<RawGrid, ServiceError> {
    let r = |a: &Option<proto::AngleRange>, name: &str| {
        a.map(|a| [a.min, a.max, a.step]).ok_or_else(|| {
            ServiceError::invalid(format!("options {what}: set {name} (min, max, step)"))
        })
    };
    Ok(RawGrid {
        yaw: r(&g.yaw, "yaw")?,
        pitch: r(&g.pitch, "pitch")?,
        roll: g.roll.map(|a| [a.min, a.max, a.step]),
    })
}

/// The header's options as raw options.
pub fn options_from_proto(o: &proto::TrainingOptions) -> Result<RawOptions, ServiceError> {
    Ok(RawOptions {
        grid: (!o.grid.is_empty()).then(|| o.grid.clone()),
        custom_grid: match &o.coarse {
            Some(c) => Some((
                raw_grid(c, "coarse")?,
                o.bins
                    .iter()
                    .enumerate()
                    .map(|(k, b)| raw_grid(b, &format!("bins[{k}]")))
                    .collect::<Result<_, _>>()?,
            )),
            None if !o.bins.is_empty() => {
                return Err(ServiceError::invalid(
                    "options: bins need a coarse grid (set options.coarse)",
                ));
            }
            None => None,
        },
        epsilons: (!o.epsilons.is_empty()).then(|| o.epsilons.clone()),
        subsets: o.subsets.as_ref().map(|s| s.names.clone()),
        components: o.components.map(|c| c as usize),
        seed: o.seed,
        min_shapes: o.min_shapes.map(|c| c as usize),
        outlier_k: o.outlier_k,
    })
}

/// Collects a Retrain stream's messages (header first) into a raw upload; `limit` caps the
/// total size of the messages.
#[derive(Debug)]
pub struct ChunkCollector {
    upload: Option<RawUpload>,
    shapes: Vec<Vec<Point3>>,
    subjects: Vec<Vec<Vec<Option<[f64; 2]>>>>,
    hasher: sha2::Sha256,
    bytes: usize,
    limit: usize,
}

impl ChunkCollector {
    /// A collector accepting at most `limit` bytes of messages in all.
    pub fn new(limit: usize) -> Self {
        ChunkCollector {
            upload: None,
            shapes: vec![],
            subjects: vec![],
            hasher: sha2::Sha256::new(),
            bytes: 0,
            limit,
        }
    }

    /// Adds one message.
    pub fn push(&mut self, chunk: proto::RetrainChunk) -> Result<(), ServiceError> {
        use prost::Message;
        let encoded = chunk.encode_to_vec();
        self.bytes += encoded.len();
        if self.bytes > self.limit {
            return Err(ServiceError::TooLarge {
                what: "the upload",
                size: None,
                limit: self.limit,
                flag: "--max-upload",
                hint: "send fewer shapes",
            });
        }
        self.hasher.update(&encoded);
        match chunk.part {
            None => Err(ServiceError::invalid(
                "empty RetrainChunk: set header, shapes or subjects",
            )),
            Some(Part::Header(h)) => {
                if self.upload.is_some() {
                    return Err(ServiceError::invalid(
                        "a second RetrainHeader: send one, first",
                    ));
                }
                let scheme = match (h.scheme.is_empty(), h.scheme_json.is_empty()) {
                    (_, true) => Some(SchemeSpec::Name(h.scheme)),
                    (true, false) => Some(SchemeSpec::Definition(Box::new(
                        serde_json::from_str::<Scheme>(&h.scheme_json)
                            .map_err(|e| ServiceError::invalid(format!("scheme_json: {e}")))?,
                    ))),
                    (false, false) => {
                        return Err(ServiceError::invalid(
                            "set scheme (a built-in name) or scheme_json, not both",
                        ));
                    }
                };
                self.upload = Some(RawUpload {
                    model: Some(h.model),
                    scheme,
                    data: None,
                    both: false,
                    options: match &h.options {
                        Some(o) => options_from_proto(o)?,
                        None => RawOptions::default(),
                    },
                    activate: h.activate,
                    notes: Some(h.notes),
                    sha256: String::new(),
                    origin: "gRPC Retrain",
                });
                Ok(())
            }
            Some(_) if self.upload.is_none() => Err(ServiceError::invalid(
                "the first RetrainChunk must be the header",
            )),
            Some(Part::Shapes(c)) => {
                let base = self.shapes.len();
                for (k, s) in c.shapes.into_iter().enumerate() {
                    if s.coords.len() % 3 != 0 {
                        return Err(ServiceError::invalid(format!(
                            "shapes[{}]: {} coordinates; give x, y, z per point",
                            base + k,
                            s.coords.len()
                        )));
                    }
                    self.shapes.push(
                        s.coords
                            .chunks_exact(3)
                            .map(|c| Point3::new(c[0], c[1], c[2]))
                            .collect(),
                    );
                }
                Ok(())
            }
            Some(Part::Subjects(c)) => {
                for s in c.subjects {
                    self.subjects.push(
                        s.views
                            .into_iter()
                            .map(|v| {
                                v.landmarks
                                    .iter()
                                    .map(|l| (!l.missing).then_some([l.x, l.y]))
                                    .collect()
                            })
                            .collect(),
                    );
                }
                Ok(())
            }
        }
    }

    /// The upload, once the stream has ended.
    pub fn finish(self) -> Result<RawUpload, ServiceError> {
        let mut u = self.upload.ok_or_else(|| {
            ServiceError::invalid("empty Retrain stream: send a RetrainHeader, then the shapes")
        })?;
        u.sha256 = format!("{:x}", self.hasher.finalize());
        u.both = !self.shapes.is_empty() && !self.subjects.is_empty();
        u.data = if !self.shapes.is_empty() {
            Some(UploadData::Shapes(self.shapes))
        } else if !self.subjects.is_empty() {
            Some(UploadData::Subjects(self.subjects))
        } else {
            None
        };
        Ok(u)
    }
}
