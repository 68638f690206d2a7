"""The Helm chart `helm/neuralbake`, rendered with Helm's own engine (helm-python-sdk bundles Helm's Go
library), linted, every core resource validated against the Kubernetes schemas of a current version, and
its values schema rejecting bad values."""

from __future__ import annotations

from pathlib import Path

import helm_python as helm
import kubernetes_validate
import pytest
import yaml

CHART = Path(__file__).resolve().parents[2] / "helm" / "neuralbake"
KUBERNETES_VERSION = kubernetes_validate.latest_version()


def render(values: dict | None = None) -> list[dict]:
    manifests = helm.Chart.load(CHART).render(values, name="nb", namespace="neuralbake")
    documents = []
    for path, text in manifests.items():
        if path.endswith(".yaml"):
            documents += [doc for doc in yaml.safe_load_all(text) if doc]
    return documents


def by_kind(documents: list[dict], kind: str) -> dict[str, dict]:
    return {doc["metadata"]["name"]: doc for doc in documents if doc["kind"] == kind}


def env_of(container: dict) -> dict[str, dict]:
    return {item["name"]: item for item in container.get("env", [])}


def test_the_chart_lints_clean_in_strict_mode():
    report = helm.lint(CHART, strict=True, kube_version=f"v{KUBERNETES_VERSION}.0")
    assert report["errors"] == []
    assert [m for m in report["messages"] if m["severity"] >= 2] == []


@pytest.mark.parametrize(
    "values",
    [None, {"inference": {"enabled": False, "replicas": 1, "port": 8090, "grpcPort": 50052,
                          "device": "auto", "memoryBytes": 1, "gpu": 0,
                          "resources": {"requests": {"cpu": "1", "memory": "1Gi"}}},
            "rayCluster": {"authTokenSecret": "ray-token"}}],
    ids=["defaults", "no-inference-with-ray-auth"],
)  # fmt: skip
def test_every_core_resource_is_valid_for_a_current_kubernetes(values):
    documents = render(values)
    core = [doc for doc in documents if doc["kind"] != "RayCluster"]
    assert core
    for document in core:
        kubernetes_validate.validate(document, KUBERNETES_VERSION, strict=True)


def test_api_and_inference_deployments_probe_health_and_take_secrets_from_secrets():
    documents = render()
    deployments = by_kind(documents, "Deployment")
    services = by_kind(documents, "Service")
    assert set(deployments) == {"nb-neuralbake-api", "nb-neuralbake-inference"}
    assert set(services) == set(deployments)
    for name, deployment in deployments.items():
        pod = deployment["spec"]["template"]["spec"]
        assert pod["securityContext"]["runAsNonRoot"] is True
        (container,) = pod["containers"]
        assert container["readinessProbe"]["httpGet"]["path"] == "/readyz"
        assert container["livenessProbe"]["httpGet"]["path"] == "/healthz"
        assert {"cpu", "memory"} <= set(container["resources"]["requests"])
        env = env_of(container)
        for secret in ("NBAKE_DATABASE_URL", "NBAKE_TOKENS", "AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
            assert "secretKeyRef" in env[secret]["valueFrom"], (name, secret)
        assert env["NBAKE_STORE_URL"]["value"].startswith("s3://")
        selector = deployment["spec"]["selector"]["matchLabels"]
        assert services[name]["spec"]["selector"] == selector
        assert selector.items() <= deployment["spec"]["template"]["metadata"]["labels"].items()
    api = deployments["nb-neuralbake-api"]["spec"]["template"]["spec"]["containers"][0]
    assert env_of(api)["RAY_ADDRESS"]["value"] == "nb-neuralbake-ray-head-svc:6379"


def test_tenant_quota_defaults_reach_the_api_as_its_environment():
    quotas = {"maxQueued": 50, "maxComputeS": 3600, "maxRunning": "none"}
    api = by_kind(render({"api": {"tenantQuotas": quotas}}), "Deployment")["nb-neuralbake-api"]
    env = env_of(api["spec"]["template"]["spec"]["containers"][0])
    assert {k: v["value"] for k, v in env.items() if k.startswith("NBAKE_TENANT_")} == {
        "NBAKE_TENANT_MAX_QUEUED": "50",
        "NBAKE_TENANT_MAX_COMPUTE_S": "3600",
        "NBAKE_TENANT_MAX_RUNNING": "none",
    }  # maxPriority left out: the server's default
    default = by_kind(render(), "Deployment")["nb-neuralbake-api"]["spec"]["template"]["spec"]
    assert not any(k.startswith("NBAKE_TENANT_") for k in env_of(default["containers"][0]))


def test_the_ray_cluster_has_a_cpu_head_and_an_autoscaled_gpu_worker_group():
    (cluster,) = by_kind(render(), "RayCluster").values()
    assert cluster["apiVersion"] == "ray.io/v1"
    head = cluster["spec"]["headGroupSpec"]["template"]["spec"]["containers"][0]
    assert "nvidia.com/gpu" not in head["resources"]["requests"]
    (group,) = cluster["spec"]["workerGroupSpecs"]
    worker = group["template"]["spec"]["containers"][0]
    assert (
        worker["resources"]["requests"]["nvidia.com/gpu"]
        == worker["resources"]["limits"]["nvidia.com/gpu"]
        == 1
    )
    assert group["minReplicas"] <= group["replicas"] <= group["maxReplicas"]
    assert cluster["spec"]["enableInTreeAutoscaling"] is True
    assert env_of(worker)["AWS_SECRET_ACCESS_KEY"]["valueFrom"]["secretKeyRef"]["name"] == "neuralbake-s3"
    assert "NBAKE_DATABASE_URL" not in env_of(worker)  # only the API process touches the database


@pytest.mark.parametrize(
    ("values", "field"),
    [
        ({"api": {"replicas": 0}}, "replicas"),
        ({"api": {"port": 70000}}, "port"),
        ({"store": {"url": "/var/lib/nbake/store"}}, "url"),  # a node-local path: not for a cluster
        ({"image": {"tag": "latest"}}, "tag"),
        ({"inference": {"device": "tpu"}}, "device"),
        ({"rayCluster": {"gpuWorkers": {"gpusPerWorker": 0}}}, "gpusPerWorker"),
        ({"podSecurityContext": {"runAsNonRoot": False}}, "runAsNonRoot"),
        ({"database": {"schema": "Bad-Schema"}}, "schema"),
        ({"api": {"resources": {"requests": {"cpu": "lots", "memory": "1Gi"}}}}, "cpu"),
        ({"api": {"tenantQuotas": {"maxQueued": -1}}}, "maxQueued"),
        ({"unknown": 1}, "unknown"),
    ],
)
def test_the_values_schema_rejects_bad_values_naming_the_field(values, field):
    with pytest.raises(helm.HelmValuesError, match=field):
        helm.Chart.load(CHART).validate_schema(values)
    with pytest.raises(helm.HelmError):
        render(values)


def test_worker_replicas_outside_the_autoscaling_bounds_fail_to_render():
    bad = {"rayCluster": {"gpuWorkers": {"minReplicas": 3, "maxReplicas": 2, "replicas": 3}}}
    with pytest.raises(helm.HelmError, match="minReplicas"):
        render(bad)
