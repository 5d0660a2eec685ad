"""File formats: point files, CARMEN logs, the map JSON schema."""
