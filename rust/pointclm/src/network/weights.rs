//! Reading a network: the safetensors state dict written by `pointclm.model.save_model` and
//! the JSON beside it, checked tensor by tensor against the architecture the JSON declares.

use std::collections::BTreeSet;
use std::path::Path;

use safetensors::{Dtype, SafeTensors};
use serde_json::{Map, Value};

use super::layers::{BatchNorm, Dense, SceneNorm};
use super::{Architecture, Block, Inputs, Network, Normalization};
use crate::config::{Assignment, Config, Pruning};
use crate::correspondences::DEFAULT_NORMAL_TOLERANCE;
use crate::error::{Error, Result};

/// The largest weight file read: far above any SCNonlocal (the paper's is 4 MB), far below
/// what a mistaken path (a disk image, a device) would make us allocate.
pub const MAX_WEIGHTS_BYTES: u64 = 4 << 30;
/// The largest metadata JSON read (the shipped ones are under 2 kB).
pub const MAX_METADATA_BYTES: u64 = 16 << 20;

/// Tensors of one [pointcn, non-local] block: conv + BatchNorm (6), q, k, v (6), and the
/// message MLP's three convs and two BatchNorms (14).
const TENSORS_PER_BLOCK: usize = 26;

pub(crate) fn read_file(path: &Path) -> Result<Network> {
    let (bytes, meta) = read_pair(path)?;
    from_bytes(&bytes, &meta, &path.display().to_string())
}

/// The bytes of a `.safetensors` file and the text of the `.json` beside it.
pub(crate) fn read_pair(path: &Path) -> Result<(Vec<u8>, String)> {
    let meta_path = path.with_extension("json");
    let bytes = read_regular(path, MAX_WEIGHTS_BYTES)?;
    let meta = read_regular(&meta_path, MAX_METADATA_BYTES)?;
    let meta = String::from_utf8(meta).map_err(|_| Error::WeightsMalformed {
        path: meta_path.display().to_string(),
        reason: "the metadata is not UTF-8 text".into(),
    })?;
    Ok((bytes, meta))
}

/// The bytes of `path`, which must be a regular file of at most `max` bytes: a FIFO would
/// block forever and a device such as `/dev/zero` never ends.
fn read_regular(path: &Path, max: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let not_found = |reason: String| Error::WeightsNotFound {
        path: path.display().to_string(),
        reason,
    };
    // `metadata` follows symlinks and does not open the file, so a FIFO is refused before
    // an `open` could block on it.
    let meta = std::fs::metadata(path).map_err(|e| not_found(e.to_string()))?;
    if !meta.is_file() {
        return Err(not_found("not a regular file".into()));
    }
    if meta.len() > max {
        return Err(Error::WeightsMalformed {
            path: path.display().to_string(),
            reason: format!(
                "{} bytes, more than the {max} a network file may have",
                meta.len()
            ),
        });
    }
    let file = std::fs::File::open(path).map_err(|e| not_found(e.to_string()))?;
    let mut bytes = Vec::new();
    bytes
        .try_reserve_exact(meta.len() as usize)
        .map_err(|_| Error::Allocation {
            what: "weights file",
            bytes: u128::from(meta.len()),
        })?;
    // `take` guards against a file that grows while it is read
    file.take(max)
        .read_to_end(&mut bytes)
        .map_err(|e| not_found(e.to_string()))?;
    Ok(bytes)
}

/// The network in `bytes` (a safetensors file) as `meta` (its JSON) declares it; `name` is the
/// path that errors report.
pub(crate) fn from_bytes(bytes: &[u8], meta: &str, name: &str) -> Result<Network> {
    let malformed = |reason: String| Error::WeightsMalformed {
        path: name.to_string(),
        reason,
    };
    let (architecture, recommended) = metadata(meta).map_err(malformed)?;
    let st = SafeTensors::deserialize(bytes)
        .map_err(|e| malformed(format!("not a safetensors file: {e}")))?;
    check_capacity(&architecture, &st, bytes.len()).map_err(malformed)?;
    let mut r = Reader {
        st: &st,
        name,
        used: BTreeSet::new(),
        scene: architecture.normalization == Normalization::Scene,
    };
    let w = architecture.width;
    let (lift, _) = r.conv("lift", w, architecture.input_channels(), None)?;
    let mut blocks = Vec::with_capacity(architecture.depth);
    for b in 0..architecture.depth {
        blocks.push(r.block(b, w)?);
    }
    // BatchNorm's step counter is training state; anything else left over means the file
    // holds a different network than its metadata says (torch's strict loading refuses it).
    let unexpected = st
        .names()
        .into_iter()
        .find(|t| !r.used.contains(*t) && !t.ends_with(".num_batches_tracked"));
    if let Some(t) = unexpected {
        return Err(malformed(format!(
            "unexpected tensor {t} for architecture depth {}, width {}",
            architecture.depth, w
        )));
    }
    Ok(Network {
        architecture,
        recommended,
        lift,
        blocks,
    })
}

/// The architecture and the recommended config (the default when absent or null) that the
/// metadata JSON declares; the error is the reason it is malformed.
fn metadata(meta: &str) -> std::result::Result<(Architecture, Config), String> {
    let meta: Value =
        serde_json::from_str(meta).map_err(|e| format!("metadata is not valid JSON: {e}"))?;
    let architecture = meta
        .get("architecture")
        .ok_or_else(|| "metadata has no \"architecture\"".to_string())
        .and_then(architecture)?;
    let recommended = match meta.get("recommended_config") {
        None | Some(Value::Null) => Config::default(),
        Some(v) => config(v).map_err(|e| format!("recommended_config: {e}"))?,
    };
    Ok((architecture, recommended))
}

/// Refuses an architecture that the file cannot hold before anything is allocated for it: a
/// JSON that says `"depth": 1000000000` must not make the reader reserve a billion blocks.
/// Every block has [`TENSORS_PER_BLOCK`] tensors and at least `4 width^2` f32 values (pointcn
/// and q, k, v), the lift `input_channels x width`.
fn check_capacity(
    a: &Architecture,
    st: &SafeTensors<'_>,
    file_bytes: usize,
) -> std::result::Result<(), String> {
    let tensors = st.len();
    let blocks_held = tensors.saturating_sub(2) / TENSORS_PER_BLOCK;
    if a.depth > blocks_held {
        return Err(format!(
            "architecture depth {} needs {} tensors; the file holds {tensors}",
            a.depth,
            a.depth.saturating_mul(TENSORS_PER_BLOCK).saturating_add(2)
        ));
    }
    let w = a.width as u128;
    let needed = (a.depth as u128)
        .saturating_mul(16)
        .saturating_mul(w)
        .saturating_mul(w)
        .saturating_add(4 * a.input_channels() as u128 * w);
    if needed > file_bytes as u128 {
        return Err(format!(
            "architecture depth {}, width {} needs at least {needed} bytes of f32 tensors; \
             the file has {file_bytes}",
            a.depth, a.width
        ));
    }
    Ok(())
}

/// Looks tensors up by name and checks their shape, dtype and values.
pub(crate) struct Reader<'a, 'd> {
    pub(crate) st: &'a SafeTensors<'d>,
    pub(crate) name: &'a str,
    pub(crate) used: BTreeSet<String>,
    /// Per-scene normalization: BatchNorms are kept apart rather than folded.
    pub(crate) scene: bool,
}

impl Reader<'_, '_> {
    pub(crate) fn tensor(&mut self, name: &str, shape: &[usize]) -> Result<Vec<f64>> {
        let view = self.st.tensor(name).map_err(|_| Error::TensorMissing {
            path: self.name.to_string(),
            name: name.to_string(),
        })?;
        if view.shape() != shape {
            return Err(Error::TensorShape {
                path: self.name.to_string(),
                name: name.to_string(),
                expected: shape.to_vec(),
                got: view.shape().to_vec(),
            });
        }
        let data = view.data();
        let values: Vec<f64> = match view.dtype() {
            Dtype::F32 => data
                .chunks_exact(4)
                .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])))
                .collect(),
            Dtype::F64 => data
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
                .collect(),
            other => {
                return Err(self.malformed(format!(
                    "tensor {name} has dtype {other:?}; F32 and F64 are supported"
                )))
            }
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(self.malformed(format!("tensor {name} has non-finite values")));
        }
        self.used.insert(name.to_string());
        Ok(values)
    }

    pub(crate) fn malformed(&self, reason: String) -> Error {
        Error::WeightsMalformed {
            path: self.name.to_string(),
            reason,
        }
    }

    /// A `Conv1d(inp, out, 1)` named `conv`, with the `BatchNorm1d(out)` named `bn` after it:
    /// folded into the convolution, or with per-scene normalization returned apart (its
    /// running statistics are still read, so that the file is checked as torch loads it).
    fn conv(
        &mut self,
        conv: &str,
        out: usize,
        inp: usize,
        bn: Option<&str>,
    ) -> Result<(Dense, Option<SceneNorm>)> {
        let weight = self.tensor(&format!("{conv}.weight"), &[out, inp, 1])?;
        let bias = self.tensor(&format!("{conv}.bias"), &[out])?;
        let bn = bn.map(|bn| self.batch_norm(bn, out)).transpose()?;
        Ok(match bn {
            Some(bn) if self.scene => (
                Dense::new(&weight, &bias, None),
                Some(SceneNorm {
                    gamma: bn.weight,
                    beta: bn.bias,
                }),
            ),
            bn => (Dense::new(&weight, &bias, bn.as_ref()), None),
        })
    }

    fn batch_norm(&mut self, bn: &str, c: usize) -> Result<BatchNorm> {
        let norm = BatchNorm {
            weight: self.tensor(&format!("{bn}.weight"), &[c])?,
            bias: self.tensor(&format!("{bn}.bias"), &[c])?,
            mean: self.tensor(&format!("{bn}.running_mean"), &[c])?,
            var: self.tensor(&format!("{bn}.running_var"), &[c])?,
        };
        if norm.var.iter().any(|&v| v < 0.0) {
            return Err(self.malformed(format!("{bn}.running_var has negative values")));
        }
        Ok(norm)
    }

    /// Block `b` (`w` channels; the message MLP narrows to `w / 2`): the torch module names
    /// `pointcn.{b}` and `nonlocal_blocks.{b}`, in the order the network reads them.
    fn block(&mut self, b: usize, w: usize) -> Result<Block> {
        let h = w / 2;
        let pc = format!("pointcn.{b}");
        let nl = format!("nonlocal_blocks.{b}");
        let (pointcn, n0) = self.conv(&format!("{pc}.0"), w, w, Some(&format!("{pc}.1")))?;
        let qkv = self.qkv(&nl, w)?;
        let msg = |k: usize| format!("{nl}.message.{k}");
        let (m0, n1) = self.conv(&msg(0), h, w, Some(&msg(1)))?;
        let (m1, n2) = self.conv(&msg(3), h, h, Some(&msg(4)))?;
        let (m2, _) = self.conv(&msg(6), w, h, None)?;
        // all three or none, as `self.scene` says
        let scene = match (n0, n1, n2) {
            (Some(a), Some(b), Some(c)) => Some(Box::new([a, b, c])),
            _ => None,
        };
        Ok(Block {
            pointcn,
            qkv,
            message: [m0, m1, m2],
            scene,
        })
    }

    /// The q, k and v convolutions of a non-local block stacked into one `w -> 3w` product.
    fn qkv(&mut self, block: &str, w: usize) -> Result<Dense> {
        let mut weight = Vec::with_capacity(3 * w * w);
        let mut bias = Vec::with_capacity(3 * w);
        for part in ["q", "k", "v"] {
            weight.extend(self.tensor(&format!("{block}.{part}.weight"), &[w, w, 1])?);
            bias.extend(self.tensor(&format!("{block}.{part}.bias"), &[w])?);
        }
        Ok(Dense::new(&weight, &bias, None))
    }
}

/// The keys of `architecture` in the metadata.
const ARCHITECTURE_KEYS: [&str; 6] = [
    "depth",
    "width",
    "sigma_d",
    "inputs",
    "normal_tolerance",
    "normalization",
];

fn architecture(v: &Value) -> std::result::Result<Architecture, String> {
    let obj = v
        .as_object()
        .ok_or_else(|| format!("architecture must be an object, got {v}"))?;
    if let Some(k) = obj
        .keys()
        .find(|k| !ARCHITECTURE_KEYS.contains(&k.as_str()))
    {
        return Err(format!("unknown architecture key {k:?}"));
    }
    let count = |key: &str| -> std::result::Result<usize, String> {
        obj.get(key)
            .and_then(Value::as_u64)
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| format!("architecture.{key} must be a non-negative integer"))
    };
    let (depth, width) = (count("depth")?, count("width")?);
    let sigma_d = obj
        .get("sigma_d")
        .and_then(Value::as_f64)
        .ok_or("architecture.sigma_d must be a number")?;
    if depth < 1 || width < 4 || width % 2 != 0 {
        return Err(format!(
            "need depth >= 1 and an even width >= 4, got depth {depth}, width {width}"
        ));
    }
    if !(sigma_d.is_finite() && sigma_d > 0.0) {
        return Err(format!("architecture.sigma_d must be > 0, got {sigma_d}"));
    }
    Ok(Architecture {
        depth,
        width,
        sigma_d,
        inputs: inputs(obj.get("inputs"))?,
        normal_tolerance: normal_tolerance(obj.get("normal_tolerance"))?,
        normalization: normalization(obj.get("normalization"))?,
    })
}

/// `architecture.normalization`: "running" or "scene" (absent: running).
fn normalization(v: Option<&Value>) -> std::result::Result<Normalization, String> {
    match v.map(Value::as_str) {
        None | Some(Some("running")) => Ok(Normalization::Running),
        Some(Some("scene")) => Ok(Normalization::Scene),
        _ => Err(format!(
            "unknown architecture.normalization {} (known: running, scene)",
            v.map_or_else(String::new, Value::to_string)
        )),
    }
}

/// `architecture.inputs`: a list of distinct input names (absent: the plain network).
fn inputs(v: Option<&Value>) -> std::result::Result<Inputs, String> {
    let mut inputs = Inputs::default();
    let Some(v) = v else {
        return Ok(inputs);
    };
    let names = v
        .as_array()
        .ok_or_else(|| format!("architecture.inputs must be a list of input names, got {v}"))?;
    for name in names {
        let flag = match name.as_str() {
            Some("normals") => &mut inputs.normals,
            Some("similarity") => &mut inputs.similarity,
            _ => {
                return Err(format!(
                    "unknown network input {name} in architecture.inputs (known: {})",
                    Inputs::NAMES.join(", ")
                ))
            }
        };
        if std::mem::replace(flag, true) {
            return Err(format!(
                "network input {name} listed twice in architecture.inputs"
            ));
        }
    }
    Ok(inputs)
}

/// `architecture.normal_tolerance`, in (0, 2] as
/// [`with_normals`](crate::Correspondences::with_normals) requires (absent: the default).
fn normal_tolerance(v: Option<&Value>) -> std::result::Result<f64, String> {
    let Some(v) = v else {
        return Ok(DEFAULT_NORMAL_TOLERANCE);
    };
    match v.as_f64() {
        Some(t) if t.is_finite() && t > 0.0 && t <= 2.0 => Ok(t),
        _ => Err(format!(
            "architecture.normal_tolerance must be a number in (0, 2], got {v}"
        )),
    }
}

/// The defaults overridden by the fields of a JSON object (the names of [`Config`]'s fields,
/// values as `pointclm.Config.to_dict()` writes them).
pub(crate) fn config(v: &Value) -> std::result::Result<Config, String> {
    let obj: &Map<String, Value> = v
        .as_object()
        .ok_or_else(|| format!("expected an object, got {v}"))?;
    let mut c = Config::default();
    for (key, v) in obj {
        let num = || v.as_f64().ok_or(format!("{key} must be a number, got {v}"));
        let int = || {
            v.as_u64()
                .and_then(|x| usize::try_from(x).ok())
                .ok_or(format!("{key} must be a non-negative integer, got {v}"))
        };
        let text = || v.as_str().ok_or(format!("{key} must be a string, got {v}"));
        let flag = || {
            v.as_bool()
                .ok_or(format!("{key} must be true or false, got {v}"))
        };
        match key.as_str() {
            "sigma_d" => c.sigma_d = num()?,
            "pruning" => {
                c.pruning = match text()? {
                    "paper" => Pruning::Paper,
                    "authors" => Pruning::AuthorsCode,
                    "none" => Pruning::Disabled,
                    other => return Err(format!("unknown pruning {other:?}")),
                }
            }
            "tau_s" => c.tau_s = num()?,
            "tau_n" => c.tau_n = int()?,
            "beta_threshold" => c.beta_threshold = num()?,
            "feature_threshold" => c.feature_threshold = num()?,
            "min_count" => c.min_count = int()?,
            "max_kept" => c.max_kept = int()?,
            "affinity_sigma" => c.affinity_sigma = num()?,
            "max_instances" => c.max_instances = if v.is_null() { None } else { Some(int()?) },
            "assignment" => {
                c.assignment = match text()? {
                    "kmeans" => Assignment::KMeans,
                    "discretize" => Assignment::Discretize,
                    other => return Err(format!("unknown assignment {other:?}")),
                }
            }
            "kmeans_restarts" => c.kmeans_restarts = int()?,
            "min_cluster_size" => c.min_cluster_size = int()?,
            "ransac_iterations" => c.ransac_iterations = int()?,
            "inlier_threshold" => c.inlier_threshold = num()?,
            "refine" => c.refine = flag()?,
            "merge_duplicates" => c.merge_duplicates = flag()?,
            other => return Err(format!("unknown config field {other:?}")),
        }
    }
    c.validate().map_err(|e| e.to_string())?;
    Ok(c)
}
