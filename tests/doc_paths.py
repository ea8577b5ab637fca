"""Walking nested YAML documents, shared by the loader property tests (rig and target)."""


def paths(doc, prefix=()):
    """Every path (tuple of keys / indices) into a nested document."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += paths(v, prefix + (i,))
    return out


def get(doc, path):
    for k in path:
        doc = doc[k]
    return doc
