//! The HUD's labels, legend entries and table, each one widget drawn from text layouts egui has cached.
//!
//! egui lays out (shapes) every label whose text it has not seen in the last pass, and a HUD whose figures
//! change ten times a second spent most of its CPU time there (`benches/hud.rs`). [`Labels`] lays out the
//! ten digits once a pass and each run of other characters through egui's cache (those repeat from one
//! refresh to the next), then puts them side by side in one galley, painted as one shape. The body font's
//! digits all have one width, so columns of figures stay aligned.

use egui::emath::GuiRounding as _;
use egui::epaint::text::{LayoutJob, PlacedRow};
use egui::{Color32, FontId, Galley, Response, Ui};
use std::sync::Arc;

/// The body font's digits, laid out for one pass.
pub struct Labels {
    font: FontId,
    digits: [Arc<Galley>; 10],
}

impl Labels {
    /// Lays out the digits in `ctx`'s body font. Galleys hold places in the font atlas, which can change from
    /// one pass to the next: make one `Labels` a pass.
    pub fn new(ctx: &egui::Context) -> Self {
        let font = egui::TextStyle::Body.resolve(&ctx.global_style());
        let digits = std::array::from_fn(|digit| {
            let text = char::from(b'0' + digit as u8).to_string();
            ctx.fonts_mut(|fonts| fonts.layout(text, font.clone(), Color32::PLACEHOLDER, f32::INFINITY))
        });
        Self { font, digits }
    }

    /// Adds `text` as a label, in the text colour.
    pub fn text(&self, ui: &mut Ui, text: &str) -> Response {
        self.coloured(ui, ui.visuals().text_color(), text)
    }

    /// Adds `text` as a label in `colour`. It does not wrap.
    pub fn coloured(&self, ui: &mut Ui, colour: Color32, text: &str) -> Response {
        let line = self.line(ui, text);
        let (rect, response) = ui.allocate_exact_size(egui::vec2(line.size().x, self.height()), egui::Sense::hover());
        if ui.is_rect_visible(rect) {
            ui.painter().galley(rect.left_top(), line, colour);
        }
        response
    }

    /// Adds a legend entry: a small square of `colour`, then `text`.
    pub fn swatch(&self, ui: &mut Ui, colour: Color32, text: &str) -> Response {
        self.legend(ui, &[(text, colour)])
    }

    /// Adds a legend of `entries`, each a small square of its colour then its name, side by side and wrapped
    /// to the width available, as one widget.
    pub fn legend(&self, ui: &mut Ui, entries: &[(&str, Color32)]) -> Response {
        let gap = ui.spacing().item_spacing;
        let available = ui.available_width();
        let lines: Vec<Arc<Galley>> = entries.iter().map(|&(name, _)| self.line(ui, name)).collect();
        // Each entry's offset from the widget's top left: a new row before an entry that would pass the width.
        let mut offsets = Vec::with_capacity(lines.len());
        let (mut x, mut y, mut width) = (0.0f32, 0.0f32, 0.0f32);
        for line in &lines {
            let entry = SQUARE + gap.x + line.size().x;
            if x > 0.0 && x + entry > available {
                (x, y) = (0.0, y + self.height() + gap.y);
            }
            offsets.push(egui::vec2(x, y));
            width = width.max(x + entry);
            x += entry + gap.x;
        }
        let height = if lines.is_empty() { 0.0 } else { y + self.height() };
        let (rect, response) = ui.allocate_exact_size(egui::vec2(width, height), egui::Sense::hover());
        if ui.is_rect_visible(rect) {
            let (painter, text_colour) = (ui.painter(), ui.visuals().text_color());
            let mut squares = egui::Mesh::default();
            for (&(_, colour), offset) in entries.iter().zip(&offsets) {
                squares.add_colored_rect(square(rect.left_top() + *offset, self.height()), colour);
            }
            painter.add(squares);
            for (line, offset) in lines.into_iter().zip(offsets) {
                painter.galley(rect.left_top() + offset + egui::vec2(SQUARE + gap.x, 0.0), line, text_colour);
            }
        }
        response
    }

    /// Adds `rows` as one table widget, striped, its columns as wide as their widest cell: a grid of labels
    /// without a widget a cell.
    pub fn table<const COLUMNS: usize>(&self, ui: &mut Ui, rows: &[TableRow<COLUMNS>]) -> Response {
        let gap = ui.spacing().item_spacing;
        let lines: Vec<[Arc<Galley>; COLUMNS]> =
            rows.iter().map(|row| std::array::from_fn(|column| self.line(ui, &row.cells[column]))).collect();
        let swatches = rows.iter().any(|row| row.swatch.is_some());
        let indent = if swatches { SQUARE + gap.x } else { 0.0 };
        let mut widths = [0.0f32; COLUMNS];
        for row in &lines {
            for (width, line) in widths.iter_mut().zip(row) {
                *width = width.max(line.size().x);
            }
        }
        widths[0] += indent;
        let row_height = self.height().max(ui.spacing().interact_size.y);
        let width = widths.iter().sum::<f32>() + gap.x * (COLUMNS - 1) as f32;
        let height = (row_height + gap.y) * rows.len() as f32 - gap.y;
        let (rect, response) = ui.allocate_exact_size(egui::vec2(width, height), egui::Sense::hover());
        if ui.is_rect_visible(rect) {
            let painter = ui.painter();
            let text_colour = ui.visuals().text_color();
            let row_top = |index: usize| rect.top() + index as f32 * (row_height + gap.y);
            let text_top = |index: usize| row_top(index) + (row_height - self.height()) / 2.0;
            // The stripes and squares as one mesh, under the text.
            let mut background = egui::Mesh::default();
            for (index, row) in rows.iter().enumerate() {
                let top = row_top(index);
                if index % 2 == 1 {
                    let stripe =
                        egui::Rect::from_x_y_ranges(rect.x_range(), top - gap.y / 2.0..=top + row_height + gap.y / 2.0);
                    background.add_colored_rect(stripe, ui.visuals().faint_bg_color);
                }
                if let Some(colour) = row.swatch {
                    background
                        .add_colored_rect(square(egui::pos2(rect.left(), text_top(index)), self.height()), colour);
                }
            }
            painter.add(background);
            for (index, line) in lines.into_iter().enumerate() {
                let text_top = text_top(index);
                let mut left = rect.left();
                for (column, line) in line.into_iter().enumerate() {
                    let shift = if column == 0 { indent } else { 0.0 };
                    painter.galley(egui::pos2(left + shift, text_top), line, text_colour);
                    left += widths[column] + gap.x;
                }
            }
        }
        response
    }

    /// Height of a line of text.
    fn height(&self) -> f32 {
        self.digits[0].size().y
    }

    /// `text` laid out from pieces, each digit from `self.digits` and each other run through egui's cache,
    /// put side by side in one galley: one shape to paint and tessellate.
    fn line(&self, ui: &Ui, text: &str) -> Arc<Galley> {
        let layout = |piece: &str| match piece.as_bytes() {
            &[digit @ b'0'..=b'9'] => self.digits[usize::from(digit - b'0')].clone(),
            _ => ui.painter().layout_no_wrap(piece.to_owned(), self.font.clone(), Color32::PLACEHOLDER),
        };
        let mut pieces = pieces(text).map(layout).peekable();
        let Some(first) = pieces.next() else { return layout("") };
        if pieces.peek().is_none() {
            return first; // Text without digits, or one digit: egui's layout as it is.
        }
        let mut line = Galley::clone(&first);
        line.job = Arc::new(LayoutJob::simple_singleline(text.to_owned(), self.font.clone(), Color32::PLACEHOLDER));
        let mut right = first.size().x;
        for piece in pieces {
            let offset = egui::vec2(right, 0.0);
            right += piece.size().x;
            for placed in &piece.rows {
                let pos = (placed.pos + offset).round_to_pixels(line.pixels_per_point);
                line.mesh_bounds |= placed.visuals.mesh_bounds.translate(pos.to_vec2());
                line.rect |= egui::Rect::from_min_size(pos, placed.size);
                line.rows.push(PlacedRow { pos, row: placed.row.clone(), ends_with_newline: false });
            }
            line.num_vertices += piece.num_vertices;
            line.num_indices += piece.num_indices;
        }
        line.rect.max.x = right;
        Arc::new(line)
    }
}

/// Side of a legend's square, in points.
const SQUARE: f32 = 10.0;

/// A legend's square, at the left of a line of text `height` high whose top left is `at`. Squares and stripes
/// are added to one mesh a widget, which egui passes on as it is: as rectangle shapes, each was tessellated
/// on its own, which cost more than the text (callgrind of `benches/hud.rs`).
fn square(at: egui::Pos2, height: f32) -> egui::Rect {
    egui::Rect::from_center_size(egui::pos2(at.x + SQUARE / 2.0, at.y + height / 2.0), egui::Vec2::splat(SQUARE))
}

/// One row of a [`Labels::table`]: its cells' text, and a legend square before the first where it has one.
pub struct TableRow<const COLUMNS: usize> {
    /// The colour of the square before the first cell.
    pub swatch: Option<Color32>,
    /// Each column's text.
    pub cells: [String; COLUMNS],
}

/// `text` cut into single ASCII digits and the runs of other characters between them.
fn pieces(text: &str) -> impl Iterator<Item = &str> {
    let mut rest = text;
    std::iter::from_fn(move || {
        let first = rest.bytes().next()?;
        let end =
            if first.is_ascii_digit() { 1 } else { rest.find(|c: char| c.is_ascii_digit()).unwrap_or(rest.len()) };
        let (piece, tail) = rest.split_at(end);
        rest = tail;
        Some(piece)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_cut_into_digits_and_the_runs_between() {
        let cut: Vec<&str> = pieces("12 of 3.5 µs").collect();
        assert_eq!(cut, ["1", "2", " of ", "3", ".", "5", " µs"]);
        assert_eq!(pieces("").count(), 0);
        assert_eq!(pieces("µs").collect::<Vec<_>>(), ["µs"]);
    }

    #[test]
    fn figures_take_the_width_of_their_text_laid_out_whole() {
        let ctx = egui::Context::default();
        let mut widths = (0.0, 0.0);
        let mut output = ctx.run_ui(egui::RawInput::default(), |ui| {
            let labels = Labels::new(ui.ctx());
            widths.0 = labels.text(ui, "1907 of 28350 µs").rect.width();
            widths.1 = ui.label("1907 of 28350 µs").rect.width();
        });
        output.textures_delta.clear();
        // Only kerning between the pieces may differ.
        assert!((widths.0 - widths.1).abs() < 2.0, "{widths:?}");
    }
}
