"""A build as a JUnit XML report, which every CI system shows: one test case per item (class: the asset,
name: the kind entry), failed on a gate, an error when its job failed, was refused or timed out; the
artifact's metrics and each gate's figure in its output."""

from __future__ import annotations

from xml.etree import ElementTree

from neuralbake_client.bake import GATES_FAILED, PASSED, BuildResult, ItemResult


def _output(item: ItemResult) -> str:
    lines = [
        f"job {item.job_id or '-'}  artifact {item.artifact_id or '-'}  reused {str(item.reused).lower()}"
    ]
    lines += [f"{name} = {value:.6g}" for name, value in sorted(item.metrics.items())]
    for gate in item.gates:
        figure = "" if gate.value is None else f": {gate.value:.6g}"
        against = "" if gate.threshold is None else f" against {gate.threshold:.6g}"
        verdict = "passed" if gate.passed else "FAILED"
        lines.append(
            f"gate {gate.gate}{figure}{against} {verdict}{' (' + gate.note + ')' if gate.note else ''}"
        )
    return "\n".join(lines) + "\n"


def junit_xml(result: BuildResult, suite: str) -> bytes:
    failures = result.count(GATES_FAILED)
    errors = sum(1 for item in result.items if item.outcome not in (PASSED, GATES_FAILED))
    root = ElementTree.Element(
        "testsuites", name=suite, tests=str(len(result.items)), failures=str(failures), errors=str(errors)
    )
    cases = ElementTree.SubElement(
        root,
        "testsuite",
        name=suite,
        tests=str(len(result.items)),
        failures=str(failures),
        errors=str(errors),
        time=f"{result.seconds:.3f}",
    )
    for item in result.items:
        case = ElementTree.SubElement(
            cases,
            "testcase",
            classname=item.asset,
            name=item.name.rsplit("/", 1)[1],
            time=f"{item.seconds:.3f}",
        )
        if item.outcome == GATES_FAILED:
            failed = [gate.gate for gate in item.gates if not gate.passed]
            ElementTree.SubElement(case, "failure", message="gates failed: " + "; ".join(failed), type="gate")
        elif item.outcome != PASSED:
            ElementTree.SubElement(
                case, "error", message=item.error or item.outcome or "", type=item.outcome or ""
            )
        ElementTree.SubElement(case, "system-out").text = _output(item)
    ElementTree.indent(root)
    return ElementTree.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"
