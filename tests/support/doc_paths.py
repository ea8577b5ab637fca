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


def mutated_docs(valid_docs, number_edits, keys, values):
    """A hypothesis strategy: a valid document after 1-3 random edits (delete, replace,
    a hostile number, insert, or another subtree copied in)."""
    import copy

    from hypothesis import strategies as st

    @st.composite
    def strategy(draw):
        doc = copy.deepcopy(draw(st.sampled_from(valid_docs)))
        for _ in range(draw(st.integers(1, 3))):
            all_paths = [p for p in paths(doc) if p]
            if not all_paths:
                break
            path = draw(st.sampled_from(all_paths))
            parent, last = get(doc, path[:-1]), path[-1]
            action = draw(st.sampled_from(["delete", "replace", "number", "insert", "copy"]))
            if action == "delete":
                del parent[last]
            elif action == "replace":
                parent[last] = draw(values)
            elif action == "number":
                # a copy: later edits must not reach into the shared list of edits
                parent[last] = copy.deepcopy(draw(st.sampled_from(number_edits)))
            elif action == "insert" and isinstance(parent, dict):
                parent[draw(keys)] = draw(values)
            elif action == "insert":
                parent.insert(last, draw(values))
            else:  # another subtree here: a camera's pose onto another, a board twice, ...
                parent[last] = copy.deepcopy(get(doc, draw(st.sampled_from(all_paths))))
        return doc

    return strategy()
