//! Gather on the tape: its constructor and its tests. What it
//! computes, forward and backward, is `kernels::gather`.

use crate::exec::Op;
use crate::kernels::index::check_addressable;
use crate::real::Real;
use crate::tape::Var;

impl<'t, T: Real> Var<'t, T> {
    /// `y[i] = self[indices[i]]`: reads an array at integer positions. Adjoint:
    /// scatter-add of `y`'s adjoint into `self`'s.
    pub fn gather(self, indices: Self) -> Self {
        self.gather_channel(indices, 1, 0)
    }

    /// `y[i] = self[indices[i] * channels + channel]`: one channel of
    /// interleaved data (texel-major RGB: `channels` = 3) at integer texel
    /// indices. Gathers from one array scatter their adjoints together, so the
    /// channels of a texel cost one pass over its cache line.
    pub fn gather_channel(self, indices: Self, channels: usize, channel: usize) -> Self {
        self.same_tape(indices, "gather");
        assert!(
            channels > 0 && channel < channels,
            "gather: channel {channel} out of range for {channels} channels"
        );
        check_addressable::<T>(self.len(), "gather");
        let op = Op::Gather {
            stride: channels as u32,
            offset: channel as u32,
        };
        self.tape.record(op, indices.len(), &[self, indices])
    }
}

#[cfg(test)]
mod tests {
    use crate::Tape;
    use crate::gradcheck::{Input, gradcheck, uniform};
    use crate::ops::tests::TOL;

    #[test]
    fn gather_reads_at_the_indices() {
        let tape = Tape::<f64>::new();
        let src = tape.constant(&[10.0, 20.0, 30.0]);
        let idx = tape.constant(&[2.0, 0.0, 2.0, 1.0]);
        assert_eq!(&*tape.value(src.gather(idx)), &[30.0, 10.0, 30.0, 20.0]);
        let idx = Input::Const(vec![2.0, 0.0, 2.0, 1.0, 4.0, 4.0, 3.0]);
        let r = gradcheck(&[Input::Var(uniform(5, -1.0, 1.0, 10)), idx], |_, x| {
            x[0].gather(x[1]).exp()
        });
        assert!(r.worst_rel_error < TOL, "gather: {r}");
    }

    #[test]
    #[should_panic(expected = "gather: index 3 out of range for an array of 3 elements")]
    fn gather_out_of_range_names_the_op() {
        let tape = Tape::<f32>::new();
        let src = tape.constant(&[1.0, 2.0, 3.0]);
        let _ = tape.value(src.gather(tape.constant(&[3.0])));
    }

    #[test]
    fn gather_channel_reads_interleaved_data() {
        let tape = Tape::<f64>::new();
        let rgb = tape.constant(&[1.0, 2.0, 3.0, 10.0, 20.0, 30.0]);
        let texel = tape.constant(&[1.0, 0.0, 1.0]);
        assert_eq!(&*tape.value(rgb.gather_channel(texel, 3, 2)), &[30.0, 3.0, 30.0]);
        assert_eq!(&*tape.value(rgb.gather_channel(texel, 3, 0)), &[10.0, 1.0, 10.0]);
        let texel = Input::Const(vec![1.0, 0.0, 3.0, 3.0, 2.0]);
        let r = gradcheck(&[Input::Var(uniform(12, -1.0, 1.0, 13)), texel], |_, x| {
            let (r, g, b) = (
                x[0].gather_channel(x[1], 3, 0),
                x[0].gather_channel(x[1], 3, 1),
                x[0].gather_channel(x[1], 3, 2),
            );
            (r * g).exp() + b.sin()
        });
        assert!(r.worst_rel_error < TOL, "gather_channel: {r}");
    }

    #[test]
    #[should_panic(expected = "gather: index 2 out of range for an array of 2 elements")]
    fn gather_channel_checks_the_texel_range() {
        let tape = Tape::<f32>::new();
        let rgb = tape.constant(&[1.0, 2.0, 3.0, 10.0, 20.0, 30.0]);
        let _ = tape.value(rgb.gather_channel(tape.constant(&[2.0]), 3, 0));
    }
}
