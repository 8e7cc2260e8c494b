//! Parameter trees as YAML values: merging layers, dotted names, and the leaf keys of a tree.

use serde_yaml::{Mapping, Value};

/// Merges `over` into `base`: mappings key by key, anything else replaced.
pub fn deep_merge(base: &mut Value, over: &Value) {
    match (base.as_mapping_mut(), over.as_mapping()) {
        (Some(b), Some(o)) => {
            for (k, v) in o {
                match b.get_mut(k) {
                    Some(slot) if slot.is_mapping() && v.is_mapping() => deep_merge(slot, v),
                    _ => {
                        b.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        _ => *base = over.clone(),
    }
}

/// A params-file mapping with dotted keys (`pnp.threshold_px: 4.0`, as rcl accepts and
/// launch_ros writes) turned into nested mappings; nested and dotted forms may mix.
pub fn undot(value: &Value) -> Value {
    let Some(m) = value.as_mapping() else { return value.clone() };
    let mut out = Value::Mapping(Default::default());
    for (k, v) in m {
        let v = undot(v);
        let entry = match k.as_str() {
            Some(name) if name.contains('.') => dotted(name, v),
            _ => {
                let mut one = Mapping::new();
                one.insert(k.clone(), v);
                Value::Mapping(one)
            }
        };
        deep_merge(&mut out, &entry);
    }
    out
}

/// `a.b.c` + value → `{a: {b: {c: value}}}`.
pub fn dotted(name: &str, value: Value) -> Value {
    name.rsplit('.').fold(value, |acc, key| {
        let mut m = Mapping::new();
        m.insert(key.into(), acc);
        Value::Mapping(m)
    })
}

/// The dotted names of every leaf of a tree (`pnp.threshold_px`, …), sorted; a non-empty
/// mapping is not a leaf, anything else (an empty mapping, a sequence, null) is.
pub fn leaf_keys(value: &Value) -> Vec<String> {
    fn walk(prefix: &str, value: &Value, out: &mut Vec<String>) {
        match value.as_mapping().filter(|m| !m.is_empty()) {
            Some(m) => {
                for (k, v) in m {
                    let key = k.as_str().map_or_else(|| format!("{k:?}"), str::to_string);
                    let name = if prefix.is_empty() { key } else { format!("{prefix}.{key}") };
                    walk(&name, v, out);
                }
            }
            None => out.push(prefix.to_string()),
        }
    }
    let mut out = Vec::new();
    walk("", value, &mut out);
    out.sort();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn yaml(text: &str) -> Value {
        serde_yaml::from_str(text).unwrap()
    }

    #[test]
    fn dotted_and_nested_keys_merge_into_one_tree() {
        let tree = undot(&yaml("pnp.threshold_px: 4.0\npnp:\n  min_inliers: 7\nseed: 1\n"));
        assert_eq!(tree, yaml("pnp: {threshold_px: 4.0, min_inliers: 7}\nseed: 1\n"));
        let mut base = yaml("pnp: {threshold_px: 8.0, refine: true}\nmethod: ransac\n");
        deep_merge(&mut base, &tree);
        assert_eq!(base, yaml("pnp: {threshold_px: 4.0, refine: true, min_inliers: 7}\nmethod: ransac\nseed: 1\n"));
    }

    #[test]
    fn leaf_keys_are_dotted_and_sorted() {
        let keys = leaf_keys(&yaml("b: {y: 1, x: [1, 2]}\na: null\nc: {}\n"));
        assert_eq!(keys, ["a", "b.x", "b.y", "c"]);
    }
}
