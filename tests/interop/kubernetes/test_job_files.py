"""examples/kubernetes/*.yaml against the Kubernetes API's own schemas (strict: an unknown or
misspelt field fails), and what makes them surgvla's sharded run: an Indexed Job whose pods
take their shard from JOB_COMPLETION_INDEX, a shard count equal to its completions, and a
merge Job on the same read-write-many claim."""

import pathlib

import kubernetes_validate
import pytest
import yaml

EXAMPLES = pathlib.Path(__file__).resolve().parents[3] / "examples" / "kubernetes"
FILES = sorted(EXAMPLES.glob("*.yaml"))
VERSIONS = ["1.29.0", "1.37.0"]


def documents(path):
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def by_name():
    return {d["metadata"]["name"]: d for path in FILES for d in documents(path)}


def env(container):
    return {e["name"]: e["value"] for e in container["env"]}


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_every_document_is_valid_for_the_api(path, version):
    for document in documents(path):
        kubernetes_validate.validate(document, version, strict=True)


def test_a_misspelt_field_is_refused():
    job = by_name()["surgvla-shards"]
    job["spec"]["completionz"] = job["spec"].pop("completions")
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(job, VERSIONS[-1], strict=True)


def test_the_shards_are_an_indexed_job_with_one_shard_per_completion():
    job = by_name()["surgvla-shards"]
    spec = job["spec"]
    assert spec["completionMode"] == "Indexed"
    container = spec["template"]["spec"]["containers"][0]
    variables = env(container)
    assert int(variables["SURGVLA_SHARDS"]) == spec["completions"]
    script = "\n".join(container["args"])
    assert '--shard "$JOB_COMPLETION_INDEX/$SURGVLA_SHARDS"' in script
    assert '"$SURGVLA_BIN"' in script and "$SURGVLA_OUT/shards/shard-" in script


def test_the_merge_reads_the_shards_from_the_same_claim():
    jobs = by_name()
    claim = jobs["surgvla-shared"]
    assert claim["spec"]["accessModes"] == ["ReadWriteMany"]
    shards, merge = jobs["surgvla-shards"], jobs["surgvla-merge"]
    for job in (shards, merge):
        volumes = job["spec"]["template"]["spec"]["volumes"]
        assert volumes[0]["persistentVolumeClaim"]["claimName"] == "surgvla-shared"
    container = merge["spec"]["template"]["spec"]["containers"][0]
    assert env(container)["SURGVLA_OUT"] == env(shards["spec"]["template"]["spec"]["containers"][0])["SURGVLA_OUT"]
    script = "\n".join(container["args"])
    assert '"$SURGVLA_BIN" merge "${shards[@]}"' in script
    assert '"$SURGVLA_BIN" validate' in script
