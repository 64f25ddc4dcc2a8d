"""Request and response bodies of the HTTP API, one module per resource (they make the OpenAPI
document complete); `fields` holds the field types they share."""
