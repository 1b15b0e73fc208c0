window.addEventListener('load', () => {
  const v = view3d, out = {webgl: !!v};
  if (v) {
    const c = document.getElementById('view3d-axes'), r = c.getBoundingClientRect(), x = r.left + r.width / 2, y = r.top + r.height / 2;
    out.start = v.snapshot();
    c.dispatchEvent(new PointerEvent('pointerdown', {pointerId: 1, pointerType: 'mouse', clientX: x, clientY: y, bubbles: true}));
    window.dispatchEvent(new PointerEvent('pointermove', {pointerId: 1, pointerType: 'mouse', clientX: x + 90, clientY: y + 30, bubbles: true}));
    window.dispatchEvent(new PointerEvent('pointerup', {pointerId: 1, pointerType: 'mouse', bubbles: true}));
    out.drag = v.snapshot();
    c.dispatchEvent(new WheelEvent('wheel', {deltaY: -400, clientX: x, clientY: y, bubbles: true, cancelable: true}));
    out.wheel = v.snapshot();
    const touch = (id, px, py) => new Touch({identifier: id, target: c, clientX: px, clientY: py});
    c.dispatchEvent(new TouchEvent('touchstart', {touches: [touch(1, x - 20, y), touch(2, x + 20, y)], bubbles: true, cancelable: true}));
    c.dispatchEvent(new TouchEvent('touchmove', {touches: [touch(1, x - 60, y), touch(2, x + 60, y)], bubbles: true, cancelable: true}));
    c.dispatchEvent(new TouchEvent('touchend', {touches: [], bubbles: true, cancelable: true}));
    out.pinch = v.snapshot();
    c.dispatchEvent(new TouchEvent('touchstart', {touches: [touch(3, x, y)], bubbles: true, cancelable: true}));
    c.dispatchEvent(new TouchEvent('touchmove', {touches: [touch(3, x - 50, y - 40)], bubbles: true, cancelable: true}));
    c.dispatchEvent(new TouchEvent('touchend', {touches: [], bubbles: true, cancelable: true}));
    out.swipe = v.snapshot();
    document.getElementById('reset3d').click();
    out.reset = v.snapshot();
  }
  document.body.setAttribute('data-probe', JSON.stringify(out));
});
