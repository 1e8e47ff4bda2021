"""The HTTP API's routers, one per resource; ``gcs_pdm.service.api.create_app`` includes them all."""
