//! JSON Schemas of the metadata files the validator checks (the files in `schemas/`, built in)
//! and [`check`], a small JSON Schema (draft 2020-12) checker for the keywords those schemas
//! and our MCAP channels use: `type`, `properties`, `required`, `additionalProperties`,
//! `items`, `enum`, `const`, `minimum`, `maximum`, `exclusiveMinimum`, `minItems`, `maxItems`,
//! `minLength`. Unknown keywords are ignored, as the specification says (so a schema using
//! more passes more). A full validator crate pulls an HTTP stack by default; these schemas need
//! a page of code.

use serde_json::Value;

/// `meta/info.json` of a LeRobot v3.0 or v2.1 dataset.
pub const LEROBOT_INFO: &str = include_str!("../../schemas/lerobot_info.schema.json");
/// surgvla's metadata (`meta/surgvla.json` in LeRobot, `surgvla.json` in RLDS).
pub const SURGVLA_META: &str = include_str!("../../schemas/surgvla_meta.schema.json");
/// `collect_report.json`, the report `collect` leaves beside a dataset.
pub const COLLECT_REPORT: &str = include_str!("../../schemas/collect_report.schema.json");
/// An RLDS version folder's `dataset_info.json`.
pub const RLDS_DATASET_INFO: &str = include_str!("../../schemas/rlds_dataset_info.schema.json");
/// The JSON Schemas of our MCAP recordings' JSON channels, by topic.
pub const MCAP_JSON_CHANNELS: &str = include_str!("../../schemas/mcap_json_channels.json");
/// An RLDS version folder's `features.json`.
pub const RLDS_FEATURES: &str = include_str!("../../schemas/rlds_features.schema.json");

/// Where `value` breaks `schema`, as (JSON pointer, problem); empty when it conforms. A schema
/// that is not JSON is one problem at "".
pub fn check_text(value: &Value, schema: &str) -> Vec<(String, String)> {
    match serde_json::from_str::<Value>(schema) {
        Ok(schema) => check(value, &schema),
        Err(e) => vec![(String::new(), format!("the schema itself is not JSON: {e}"))],
    }
}

/// Where `value` breaks `schema` (see the module overview for the keywords understood).
pub fn check(value: &Value, schema: &Value) -> Vec<(String, String)> {
    let mut problems = Vec::new();
    walk(value, schema, "", &mut problems);
    problems
}

fn type_name(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "boolean",
        Value::Number(n) if n.is_i64() || n.is_u64() => "integer",
        Value::Number(_) => "number",
        Value::String(_) => "string",
        Value::Array(_) => "array",
        Value::Object(_) => "object",
    }
}

fn is_type(value: &Value, wanted: &str) -> bool {
    let actual = type_name(value);
    actual == wanted
        || wanted == "number" && actual == "integer"
        || wanted == "integer" && value.as_f64().is_some_and(|v| v.fract() == 0.0)
}

/// Problems found: (JSON pointer, what is wrong).
type Problems = Vec<(String, String)>;

fn walk(value: &Value, schema: &Value, pointer: &str, problems: &mut Problems) {
    let Some(schema) = schema.as_object() else {
        if schema == &Value::Bool(false) {
            problems.push((pointer.into(), "is not allowed here".into()));
        }
        return;
    };
    if !check_type(value, schema, pointer, problems) {
        return;
    }
    check_value(value, schema, pointer, problems);
    if let Some(items) = value.as_array() {
        check_items(items, schema, pointer, problems);
    }
    if let Some(object) = value.as_object() {
        check_object(object, schema, pointer, problems);
    }
}

/// `type`: whether the value has one of the types allowed (if not, nothing else is checked).
fn check_type(
    value: &Value,
    schema: &serde_json::Map<String, Value>,
    pointer: &str,
    problems: &mut Problems,
) -> bool {
    let Some(wanted) = schema.get("type") else {
        return true;
    };
    let types: Vec<&str> = match wanted {
        Value::String(t) => vec![t.as_str()],
        Value::Array(ts) => ts.iter().filter_map(Value::as_str).collect(),
        _ => Vec::new(),
    };
    if !types.is_empty() && !types.iter().any(|t| is_type(value, t)) {
        let message = format!(
            "is {} where {} is required",
            type_name(value),
            types.join(" or ")
        );
        problems_push(problems, pointer, message);
        return false;
    }
    true
}

/// `enum`, `const`, numeric bounds and `minLength`.
fn check_value(
    value: &Value,
    schema: &serde_json::Map<String, Value>,
    pointer: &str,
    problems: &mut Problems,
) {
    let mut problem = |message: String| problems_push(problems, pointer, message);
    if let Some(Value::Array(options)) = schema.get("enum")
        && !options.contains(value)
    {
        problem(format!(
            "is {value}, not one of {}",
            Value::from(options.clone())
        ));
    }
    if let Some(constant) = schema.get("const")
        && constant != value
    {
        problem(format!("is {value}, not {constant}"));
    }
    if let Some(number) = value.as_f64() {
        let bound = |key: &str| schema.get(key).and_then(Value::as_f64);
        if let Some(min) = bound("minimum")
            && number < min
        {
            problem(format!("is {number}, below the minimum {min}"));
        }
        if let Some(min) = bound("exclusiveMinimum")
            && number <= min
        {
            problem(format!("is {number}, not above {min}"));
        }
        if let Some(max) = bound("maximum")
            && number > max
        {
            problem(format!("is {number}, above the maximum {max}"));
        }
    }
    if let (Some(text), Some(min)) = (
        value.as_str(),
        schema.get("minLength").and_then(Value::as_u64),
    ) && (text.chars().count() as u64) < min
    {
        problem(format!("is shorter than {min} characters"));
    }
}

/// `minItems`, `maxItems` and each item against `items`.
fn check_items(
    items: &[Value],
    schema: &serde_json::Map<String, Value>,
    pointer: &str,
    problems: &mut Problems,
) {
    let count = |key: &str| schema.get(key).and_then(Value::as_u64);
    if let Some(min) = count("minItems")
        && (items.len() as u64) < min
    {
        let message = format!("has {} items, fewer than {min}", items.len());
        problems_push(problems, pointer, message);
    }
    if let Some(max) = count("maxItems")
        && (items.len() as u64) > max
    {
        let message = format!("has {} items, more than {max}", items.len());
        problems_push(problems, pointer, message);
    }
    if let Some(item_schema) = schema.get("items") {
        for (i, item) in items.iter().enumerate() {
            walk(item, item_schema, &format!("{pointer}/{i}"), problems);
        }
    }
}

/// `required`, each key against its `properties` entry or `additionalProperties`.
fn check_object(
    object: &serde_json::Map<String, Value>,
    schema: &serde_json::Map<String, Value>,
    pointer: &str,
    problems: &mut Problems,
) {
    if let Some(Value::Array(required)) = schema.get("required") {
        for key in required.iter().filter_map(Value::as_str) {
            if !object.contains_key(key) {
                problems_push(
                    problems,
                    pointer,
                    format!("lacks the required key \"{key}\""),
                );
            }
        }
    }
    let properties = schema.get("properties").and_then(Value::as_object);
    for (key, item) in object {
        let child = format!("{pointer}/{key}");
        match properties.and_then(|p| p.get(key)) {
            Some(property) => walk(item, property, &child, problems),
            None => match schema.get("additionalProperties") {
                Some(Value::Bool(false)) => problems_push(
                    problems,
                    pointer,
                    format!("has an unexpected key \"{key}\""),
                ),
                Some(extra @ Value::Object(_)) => walk(item, extra, &child, problems),
                _ => {}
            },
        }
    }
}

fn problems_push(problems: &mut Problems, pointer: &str, message: String) {
    problems.push((pointer.to_string(), message));
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn reports_each_keyword_with_its_pointer() {
        let schema = json!({
            "type": "object",
            "required": ["fps", "features"],
            "additionalProperties": false,
            "properties": {
                "fps": {"type": "integer", "minimum": 1},
                "name": {"type": "string", "minLength": 1},
                "version": {"enum": ["v3.0", "v2.1"]},
                "features": {"type": "object", "additionalProperties": {
                    "type": "object", "required": ["dtype"],
                    "properties": {"shape": {"type": "array", "items": {"type": "integer"}, "minItems": 1}}
                }}
            }
        });
        assert!(check(&json!({"fps": 10, "features": {}}), &schema).is_empty());
        let problems = check(
            &json!({"fps": 0, "name": "", "version": "v1", "extra": 1,
                    "features": {"a": {"shape": [1.5]}, "b": {"dtype": "x", "shape": []}}}),
            &schema,
        );
        let text: Vec<String> = problems.iter().map(|(p, m)| format!("{p} {m}")).collect();
        for expected in [
            "/fps is 0, below the minimum 1",
            "/name is shorter than 1 characters",
            "/version is \"v1\", not one of [\"v3.0\",\"v2.1\"]",
            " has an unexpected key \"extra\"",
            "/features/a lacks the required key \"dtype\"",
            "/features/a/shape/0 is number where integer is required",
            "/features/b/shape has 0 items, fewer than 1",
        ] {
            assert!(
                text.iter().any(|t| t == expected),
                "{expected} not in {text:?}"
            );
        }
        assert_eq!(problems.len(), 7);
        assert_eq!(
            check(&json!("x"), &json!({"type": ["integer", "null"]})).len(),
            1
        );
        assert!(check(&json!(null), &json!({"type": ["integer", "null"]})).is_empty());
    }

    #[test]
    fn built_in_schemas_are_json_objects() {
        for schema in [
            LEROBOT_INFO,
            SURGVLA_META,
            COLLECT_REPORT,
            RLDS_DATASET_INFO,
            RLDS_FEATURES,
        ] {
            let value: Value = serde_json::from_str(schema).expect("schema is JSON");
            assert_eq!(
                value["$schema"],
                "https://json-schema.org/draft/2020-12/schema"
            );
        }
    }
}
