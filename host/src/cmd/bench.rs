//! `msr bench`: the pipeline's costs per model, on the Cortex-M4 image in QEMU or on this PC.
use crate::bench::{bench_host, bench_qemu, from_file, print_table, synthetic_with, Backend, SynthWeights};
use crate::models::ArchKind;
use anyhow::{Context, Result};
use serde_json::Value;
use std::path::PathBuf;

/// `msr bench`'s flags: where to measure, which blobs, and how to print the figures.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Where the pipeline runs: the Cortex-M4 image in QEMU (instruction counts) or this PC
    /// (nanoseconds)
    #[arg(long, value_enum, default_value = "qemu")]
    pub backend: Backend,
    /// Model blob(s) to benchmark; default: synthetic conv and published-MLP blobs, 58 x 75.
    #[arg(long)]
    pub model: Vec<PathBuf>,
    /// Print JSON (one object per model, a list when several) instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Also write the benchmarked blobs to DIR as `<model>.msrm` (e.g. to build one into an
    /// image with `MSR_MODEL_BLOB`).
    #[arg(long, value_name = "DIR")]
    pub save_models: Option<PathBuf>,
    /// Host backend: repetitions per stage and frame.
    #[arg(long, default_value_t = 50)]
    pub reps: usize,
    /// Weight type of the synthetic blobs (`msr quantize --weights auto` takes i16 when the
    /// blob fits a board upload slot; the board runs both, i16 faster).
    #[arg(long, value_enum, default_value = "i16")]
    pub weights: SynthWeights,
}

/// Benchmarks the models (given or synthetic) on the chosen backend and prints a table or JSON.
pub fn run(args: Args) -> Result<()> {
    let models = if args.model.is_empty() {
        let i8w = args.weights == SynthWeights::I8;
        vec![synthetic_with(ArchKind::Conv, i8w)?, synthetic_with(ArchKind::Mlp, i8w)?]
    } else {
        args.model.iter().map(|p| from_file(p)).collect::<Result<Vec<_>>>()?
    };
    if let Some(dir) = &args.save_models {
        let names = save_names(&models.iter().map(|m| m.name.as_str()).collect::<Vec<_>>());
        let paths: Vec<PathBuf> = names.iter().map(|n| dir.join(format!("{n}.msrm"))).collect();
        // Every name checked before the first is written.
        let inputs: Vec<(&str, &std::path::Path)> = args.model.iter().map(|m| ("--model", m.as_path())).collect();
        let outputs: Vec<(&str, &std::path::Path)> = paths.iter().map(|p| ("--save-models", p.as_path())).collect();
        crate::fsio::check_outputs(&inputs, &outputs)?;
        for p in &paths {
            crate::fsio::refuse_special(p)?;
        }
        if dir.exists() && !dir.is_dir() {
            anyhow::bail!("--save-models {} is a file, not a folder", dir.display());
        }
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for (m, p) in models.iter().zip(&paths) {
            crate::fsio::write(p, &m.blob)?;
            eprintln!("wrote {} ({} bytes)", p.display(), m.blob.len());
        }
    }
    let mut out = Vec::new();
    for m in &models {
        let v = match args.backend {
            Backend::Qemu => bench_qemu(m)?,
            Backend::Host => bench_host(m, args.reps.max(1))?,
        };
        if !args.json {
            print_table(&v);
        }
        out.push(v);
    }
    if args.json {
        let v = if out.len() == 1 { out.remove(0) } else { Value::Array(out) };
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    Ok(())
}

/// One file name a model: its kind, and when several share a kind, `-1`, `-2`, ... in the order
/// given (`conv-1`, `conv-2`).
pub fn save_names(kinds: &[&str]) -> Vec<String> {
    kinds
        .iter()
        .enumerate()
        .map(|(i, k)| {
            if kinds.iter().filter(|o| *o == k).count() == 1 {
                k.to_string()
            } else {
                format!("{k}-{}", kinds[..=i].iter().filter(|o| *o == k).count())
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn two_models_of_one_kind_get_two_names() {
        assert_eq!(super::save_names(&["conv", "published-mlp"]), ["conv", "published-mlp"]);
        assert_eq!(super::save_names(&["conv", "mlp", "conv"]), ["conv-1", "mlp", "conv-2"]);
    }
}
