"""What the operators do with the selection after they make an object."""


def select_only(context, obj) -> None:
    """Deselect everything in the view layer, then select ``obj`` and make it active (as Blender's own "add"
    operators leave a new object)."""
    for o in context.view_layer.objects.selected:
        if o is not None:  # an object deleted by the operator (a replaced rig) is listed as None until an update
            o.select_set(False)
    context.view_layer.objects.active = obj
    obj.select_set(True)
