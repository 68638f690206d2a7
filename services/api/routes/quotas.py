"""`/v1/tenants/{tenant}/quotas` (admin): set a tenant's own quotas, and read them with what the tenant
uses now. A field left out (or null) takes the deployment's default (`NBAKE_TENANT_MAX_*`)."""

from __future__ import annotations

from datetime import datetime

from fastapi import APIRouter
from pydantic import BaseModel, Field

from services.api.deps import ServicesDep
from services.api.services import Services
from services.jobs.quotas import QuotaLimits, QuotaUse
from services.jobs.tenants import checked_tenant
from services.platform.auth import IsAdmin
from services.platform.problems import PROBLEM_RESPONSES

router = APIRouter(
    prefix="/v1/tenants", tags=["tenants"], responses={s: PROBLEM_RESPONSES[s] for s in (401, 403, 422)}
)


class TenantQuotas(BaseModel):
    tenant: str
    limits: QuotaLimits = Field(description="In force: the tenant's own where set, else the default.")
    own: QuotaLimits = Field(description="Set for this tenant (null: the default's).")
    defaults: QuotaLimits = Field(description="The deployment's, for every tenant.")
    use: QuotaUse = Field(description="What its jobs hold now.")
    updated_at: datetime | None = Field(description="When the tenant's own were last set; null: never.")


@router.put("/{tenant}/quotas", response_model=TenantQuotas)
def set_quotas(tenant: str, body: QuotaLimits, svc: ServicesDep, _: IsAdmin) -> TenantQuotas:
    """Replace the tenant's own quotas (a field left out or null: the default). Jobs already queued or
    running stay; new submissions and the scheduler's next start follow the new limits."""
    svc.quotas.set(checked_tenant(tenant), body)
    return _view(svc, tenant)


@router.get("/{tenant}/quotas", response_model=TenantQuotas)
def get_quotas(tenant: str, svc: ServicesDep, _: IsAdmin) -> TenantQuotas:
    """The tenant's quotas in force, its own, the defaults, and its use now (any tenant name: one without
    jobs or its own quotas has the defaults and no use)."""
    return _view(svc, checked_tenant(tenant))


def _view(svc: Services, tenant: str) -> TenantQuotas:
    own, updated_at = svc.quotas.override(tenant)
    return TenantQuotas(
        tenant=tenant,
        limits=svc.quotas.defaults.over(own),
        own=own,
        defaults=svc.quotas.defaults,
        use=svc.quotas.use(tenant),
        updated_at=updated_at,
    )
