"""The inference service over REST: queries as binary bodies (a JSON header line, then raw arrays), images
as EXR or PNG by `Accept`, the same problem+json errors as the job API.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from numpy.typing import ArrayLike

from neuralbake_client.answers import QueryAnswer, RenderedImage, frame_time
from neuralbake_client.arrays import OCTET_STREAM, decode_binary, encode_binary
from neuralbake_client.models import ModelInfo
from neuralbake_client.transport_http import HttpTransport


class HttpInference:
    def __init__(self, url: str, token: str | None, timeout: float):
        self.http = HttpTransport(url, token, timeout)

    def close(self) -> None:
        self.http.close()

    def models(self) -> list[ModelInfo]:
        return [ModelInfo.model_validate(m) for m in self.http.send("GET", "/v1/models").json()]

    def load(self, artifact_id: str) -> ModelInfo:
        return ModelInfo.model_validate(self.http.send("POST", f"/v1/models/{artifact_id}:load").json())

    def query(
        self,
        artifact_id: str,
        params: dict[str, Any],
        arrays: Mapping[str, ArrayLike],
        operation: str = "query",
    ) -> QueryAnswer:
        response = self.http.send(
            "POST",
            f"/v1/artifacts/{artifact_id}:{operation}",
            content=encode_binary({"params": params}, arrays),
            headers={"Content-Type": OCTET_STREAM, "Accept": OCTET_STREAM},
        )
        head, answer = decode_binary(response.content)
        return QueryAnswer(head["artifact_id"], head["kind"], answer, head.get("meta") or {})

    def render(
        self, artifact_id: str, params: dict[str, Any], arrays: Mapping[str, ArrayLike], media_type: str
    ) -> RenderedImage:
        response = self.http.send(
            "POST",
            f"/v1/artifacts/{artifact_id}:render",
            content=encode_binary({"params": params}, arrays),
            headers={"Content-Type": OCTET_STREAM, "Accept": media_type},
        )
        sent = response.headers.get("content-type", media_type).split(";")[0].strip()
        timing = frame_time(response.headers.get("server-timing"))
        return RenderedImage(artifact_id, sent, response.content, timing)
