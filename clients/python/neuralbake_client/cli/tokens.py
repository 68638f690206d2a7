"""`nbake tokens create | list | revoke | quota` (an admin token): each token belongs to a tenant and sees
only that tenant's jobs, assets and artifacts; admin tokens see every tenant. The server stores a token's
sha256 only, so `create` shows the secret once. `quota` shows or sets a tenant's quotas.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import typer

from neuralbake_client.cli.output import Output
from neuralbake_client.cli.remote import JsonOption, TokenOption, UrlOption, connect, remote_errors
from neuralbake_client.durations import seconds

if TYPE_CHECKING:
    from neuralbake_client.models import QuotaLimits, TenantQuotas, Token

DEFAULT = "default"  # a quota option's value that drops the tenant's own limit for the deployment's

tokens_app = typer.Typer(
    name="tokens",
    help="Create, list and revoke the server's tokens, and set tenants' quotas (needs an admin token).",
    no_args_is_help=True,
)


def _fields(token: Token) -> dict:
    return token.model_dump(mode="json")


def _line(token: Token) -> str:
    name = f"  {token.name}" if token.name else ""
    return (
        f"{token.id}  {token.tenant}  {token.scope:<6}  {token.source:<10}  {token.created_at:%Y-%m-%d}{name}"
    )


@tokens_app.command("create")
def create_command(
    tenant: Annotated[
        str, typer.Option(help="Whose jobs, assets and artifacts it sees and makes.")
    ] = "default",
    scope: Annotated[str, typer.Option(help="read, submit or admin (admin sees every tenant).")] = "read",
    name: Annotated[str, typer.Option(help="Who or what holds it (shown by `list`).")] = "",
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Create a token; its secret is printed once (stdout), and only its hash is kept."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        created = client.create_token(tenant, scope, name)
    if out.json:
        out.line("token", **_fields(created))
        return
    print(created.token)
    out.console.print(f"{_line(created)}\n[dim]keep the token above now: it is not shown again[/dim]")


@tokens_app.command("list")
def list_command(json_lines: JsonOption = False, url: UrlOption = None, token: TokenOption = None) -> None:
    """List the tokens (never their secrets): id, tenant, scope, source, created."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        tokens = client.tokens()
    for listed in tokens:
        if out.json:
            out.line("token", **_fields(listed))
        else:
            print(_line(listed))


@tokens_app.command("revoke")
def revoke_command(
    token_id: Annotated[str, typer.Argument(help="The token's id (`tok-...`, from `list`), not its secret.")],
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Revoke a created token: its next request gets 401."""
    out = Output(json_lines)
    with remote_errors(), connect(url, token) as client:
        client.revoke_token(token_id)
    if out.json:
        out.line("revoked", id=token_id)
    else:
        print(f"revoked {token_id}")


@tokens_app.command("quota")
def quota_command(
    tenant: Annotated[str, typer.Argument(help="The tenant whose quotas to show or set.")],
    max_running: Annotated[
        str | None, typer.Option(help="Jobs running at once (0 holds its queue), or `default`.")
    ] = None,
    max_queued: Annotated[str | None, typer.Option(help="Jobs waiting to start, or `default`.")] = None,
    max_compute: Annotated[
        str | None,
        typer.Option(
            help="Estimated compute of its queued and running jobs: 90s, 30m, 4h, 2d, or `default`."
        ),
    ] = None,
    max_priority: Annotated[
        str | None, typer.Option(help="The highest priority its jobs may ask, or `default`.")
    ] = None,
    json_lines: JsonOption = False,
    url: UrlOption = None,
    token: TokenOption = None,
) -> None:
    """Show a tenant's quotas and what its jobs use now; with options, change those quotas first (the
    others stay as they are). A submission over the queued or compute quota gets 429."""
    out = Output(json_lines)
    changes = {
        name: value
        for name, value in (
            ("max_running", _count(max_running, "--max-running", 0)),
            ("max_queued", _count(max_queued, "--max-queued", 0)),
            ("max_compute_s", _duration(max_compute)),
            ("max_priority", _count(max_priority, "--max-priority", -1000)),
        )
        if value is not None
    }
    with remote_errors(), connect(url, token) as client:
        quotas = client.quotas(tenant)
        if changes:
            own = quotas.own.model_copy(update={k: None if v == DEFAULT else v for k, v in changes.items()})
            quotas = client.set_quotas(tenant, own)
    if out.json:
        out.line("quotas", **quotas.model_dump(mode="json"))
        return
    print(_quota_lines(quotas))


def _count(value: str | None, option: str, lowest: int) -> int | str | None:
    if value is None or value == DEFAULT:
        return value
    try:
        number = int(value)
    except ValueError:
        number = lowest - 1
    if number < lowest:
        raise typer.BadParameter(f"{value!r}: a whole number from {lowest}, or `default`", param_hint=option)
    return number


def _duration(value: str | None) -> float | str | None:
    """`90`, `90s`, `30m`, `4h`, `2d` as seconds; `default` as it is."""
    if value is None or value == DEFAULT:
        return value
    try:
        return seconds(value)
    except ValueError as error:
        raise typer.BadParameter(str(error), param_hint="--max-compute") from None


def _quota_lines(quotas: TenantQuotas) -> str:
    limits, use = quotas.limits, quotas.use
    rows = [
        ("running", f"{use.running} of {_limit(limits.max_running)}", "max_running"),
        ("queued", f"{use.queued} of {_limit(limits.max_queued)}", "max_queued"),
        ("compute", f"{_hours(use.compute_s)} of {_limit(limits.max_compute_s, _hours)}", "max_compute_s"),
        ("priority", f"at most {_limit(limits.max_priority)}", "max_priority"),
    ]
    lines = [f"tenant {quotas.tenant}"]
    lines += [f"  {name:<9} {text:<24} {_source(quotas.own, field)}" for name, text, field in rows]
    return "\n".join(lines)


def _limit(value, shown=str) -> str:
    return "unlimited" if value is None else shown(value)


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.3g}h" if seconds >= 3600 else f"{seconds:.3g}s"


def _source(own: QuotaLimits, field: str) -> str:
    return "(own)" if getattr(own, field) is not None else "(default)"
