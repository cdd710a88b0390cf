"""USD stage access: scene extraction, schema helpers, authoring, validation rules."""
