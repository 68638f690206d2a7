{{- define "neuralbake.name" -}}
{{- .Chart.Name | trunc 63 | trimSuffix "-" -}}
{{- end -}}

{{- define "neuralbake.fullname" -}}
{{- if contains .Chart.Name .Release.Name -}}
{{- .Release.Name | trunc 63 | trimSuffix "-" -}}
{{- else -}}
{{- printf "%s-%s" .Release.Name .Chart.Name | trunc 63 | trimSuffix "-" -}}
{{- end -}}
{{- end -}}

{{- define "neuralbake.labels" -}}
app.kubernetes.io/name: {{ include "neuralbake.name" . }}
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/version: {{ .Chart.AppVersion | quote }}
app.kubernetes.io/managed-by: {{ .Release.Service }}
helm.sh/chart: {{ printf "%s-%s" .Chart.Name .Chart.Version }}
{{- end -}}

{{- define "neuralbake.selector" -}}
app.kubernetes.io/name: {{ include "neuralbake.name" .root }}
app.kubernetes.io/instance: {{ .root.Release.Name }}
app.kubernetes.io/component: {{ .component }}
{{- end -}}

{{- define "neuralbake.image" -}}
{{- printf "%s/%s:%s" .root.Values.image.registry .name (.tag | default .root.Values.image.tag) -}}
{{- end -}}

{{- define "neuralbake.rayClusterName" -}}
{{- printf "%s-ray" (include "neuralbake.fullname" .) | trunc 50 | trimSuffix "-" -}}
{{- end -}}

{{/* The store's location and credentials: every process that reads or writes artifacts gets them. */}}
{{- define "neuralbake.storeEnv" -}}
- name: NBAKE_STORE_URL
  value: {{ .Values.store.url | quote }}
- name: AWS_ACCESS_KEY_ID
  valueFrom:
    secretKeyRef: {name: {{ .Values.store.existingSecret }}, key: AWS_ACCESS_KEY_ID}
- name: AWS_SECRET_ACCESS_KEY
  valueFrom:
    secretKeyRef: {name: {{ .Values.store.existingSecret }}, key: AWS_SECRET_ACCESS_KEY}
- name: AWS_DEFAULT_REGION
  value: {{ .Values.store.region | quote }}
{{- with .Values.store.endpointUrl }}
- name: AWS_ENDPOINT_URL
  value: {{ . | quote }}
{{- end }}
{{- end -}}

{{/* The database and the tokens: only the API and inference processes touch them. */}}
{{- define "neuralbake.databaseEnv" -}}
- name: NBAKE_DATABASE_URL
  valueFrom:
    secretKeyRef: {name: {{ .Values.database.existingSecret }}, key: {{ .Values.database.urlKey }}}
{{- with .Values.database.schema }}
- name: NBAKE_DATABASE_SCHEMA
  value: {{ . | quote }}
{{- end }}
- name: NBAKE_TOKENS
  valueFrom:
    secretKeyRef: {name: {{ .Values.tokens.existingSecret }}, key: {{ .Values.tokens.key }}}
{{- end -}}

{{- define "neuralbake.rayAuthEnv" -}}
{{- with .Values.rayCluster.authTokenSecret }}
- name: RAY_AUTH_MODE
  value: token
- name: RAY_AUTH_TOKEN
  valueFrom:
    secretKeyRef: {name: {{ . }}, key: {{ $.Values.rayCluster.authTokenKey }}}
{{- end }}
{{- end -}}

{{- define "neuralbake.containerSecurity" -}}
allowPrivilegeEscalation: false
readOnlyRootFilesystem: true
capabilities:
  drop: [ALL]
{{- end -}}

{{- define "neuralbake.httpProbes" -}}
readinessProbe:
  httpGet: {path: /readyz, port: http}
  periodSeconds: 10
  failureThreshold: 3
livenessProbe:
  httpGet: {path: /healthz, port: http}
  initialDelaySeconds: 10
  periodSeconds: 20
  failureThreshold: 3
startupProbe:
  httpGet: {path: /healthz, port: http}
  periodSeconds: 5
  failureThreshold: 60
{{- end -}}
