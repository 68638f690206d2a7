"""`nbake tokens create | list | revoke` (an admin token): each token belongs to a tenant and sees only
that tenant's jobs, assets and artifacts; admin tokens see every tenant. The server stores a token's
sha256 only, so `create` shows the secret once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import typer

from neuralbake_client.cli.output import Output
from neuralbake_client.cli.remote import JsonOption, TokenOption, UrlOption, connect, remote_errors

if TYPE_CHECKING:
    from neuralbake_client.models import Token

tokens_app = typer.Typer(
    name="tokens",
    help="Create, list and revoke the server's tokens (needs an admin token).",
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
